"""The ABPS fix stage on routes it was not tuned on (issue 11): cycles from the firing schedule, motion
compensation from the filter's belief, an honest fix covariance and consensus outlier rejection.

Each test builds its own small input from a generator written here (the firing schedule, ranges from a
known trajectory) and checks the solver against that generator's truth or an independent algorithm
(scipy.optimize.least_squares), or against chi-square statistics over many seeded trials.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from fusion.api import Belief, BuildContext, Message, ReadsBelief, StateLayout
from fusion_plugins.solvers.firing_schedule import FiringSchedule
from fusion_plugins.solvers.ols_trilateration import OlsParams, OlsTrilateration, trilaterate, unpack_fix
from fusion_plugins.solvers.range_fix import NoFix

MINE = {f"B{i + 1}": np.array([5.0 * i, 0.1 if i % 2 == 0 else 2.9, -0.9]) for i in range(7)}
INS = StateLayout.parse("p:3 v:3 q:4:quaternion ba:3 bw:3")
C = 343.0


def firings(route, names, period=0.4, spacing=0.05, n_cycles=20, t0=0.3, reach=12.0, tof=True, drop=None):
    """The generator: beacon j of cycle n fires at t0 + n period + j spacing; the pulse arrives at the receiver
    (``route(t)`` -> position) after |p - B| / c (fixed point). Returns [(t_arrival, beacon, range, cycle)]."""
    out = []
    for n in range(n_cycles):
        for j, name in enumerate(names):
            te = t0 + n * period + j * spacing
            ta = te
            for _ in range(8):
                ta = te + np.linalg.norm(route(ta) - MINE[name]) / C if tof else te
            r = float(np.linalg.norm(route(ta) - MINE[name]))
            if r > reach or (drop is not None and drop(n, name)):
                continue
            out.append((ta, name, r, n))
    return sorted(out)


# --------------------------------------------------------------------------- 1. cycles from the schedule
@pytest.mark.parametrize("period", [0.4, None])
def test_a_beacon_early_in_the_order_coming_into_range_never_merges_two_cycles(period):
    """Finding 1: the vehicle drives towards B1 (first in the firing order), out of reach at first; when it
    comes into range its range must join its own cycle, not close/merge cycles by a repeat. Every cycle out
    of the schedule equals the generator's cycle (period given or learnt)."""
    route = lambda t: np.array([14.0 - 1.0 * t, 1.5, -0.75])                       # noqa: E731
    stream = firings(route, list(MINE), n_cycles=25)
    assert {n for _, b, _, n in stream if b == "B1"} != set(range(25))          # B1 really appears later
    sched = FiringSchedule(period, speed_of_sound=C, learn_s=2.0)
    cycles = [c for t, b, r, _ in stream for c in sched.add(t, b, r)] + sched.flush()
    truth: dict[int, set] = {}
    for t, b, r, n in stream:
        truth.setdefault(n, set()).add((b, round(t, 9)))
    got = [{(c[1], round(c[0], 9)) for c in cyc} for cyc in cycles]
    assert sorted(map(sorted, got)) == sorted(map(sorted, truth.values()))
    assert sched.period == pytest.approx(0.4, abs=1e-6) and sched.splits == 0


def test_cycles_follow_a_schedule_without_idle_time_and_missing_ranges():
    """Eleven beacons spread evenly over the period (no idle gap: the next cycle's first firing follows the
    last at once), random dropouts and time of flight up to 35 ms, the period learnt. Without an idle gap the
    timing cannot tell which slot starts a cycle, so a cycle is any run of consecutive slots within one
    period: each holds distinct beacons emitted less than a period apart, none is lost, and there are as
    many cycles as firing periods (one more at most: the first and last are partial)."""
    names = list(MINE) + ["X1", "X2", "X3", "X4"]
    for i, n in enumerate(names[7:]):
        MINE[n] = np.array([2.5 + 10.0 * i, 1.5, -0.9])
    try:
        rng = np.random.default_rng(3)
        drops = {(n, b) for n in range(30) for b in names if rng.random() < 0.15}
        route = lambda t: np.array([3.0 + 0.8 * t, 1.0 + 0.3 * np.sin(t), -0.75])   # noqa: E731
        stream = firings(route, names, period=0.4, spacing=0.4 / 11, n_cycles=30, drop=lambda n, b: (n, b) in drops)
        sched = FiringSchedule(None, speed_of_sound=C)
        cycles = [c for t, b, r, _ in stream for c in sched.add(t, b, r)] + sched.flush()
        n_periods = len({n for *_, n in stream})
        for cyc in cycles:
            names_c = [c[1] for c in cyc]
            assert len(set(names_c)) == len(names_c)
            assert max(c[3] for c in cyc) - min(c[3] for c in cyc) < 0.4 - 0.4 / 11 + 1e-6
        assert sum(len(c) for c in cycles) == len(stream)                       # none lost
        assert n_periods <= len(cycles) <= n_periods + 1
        assert sched.period == pytest.approx(0.4, abs=1e-6)
    finally:
        for n in names[7:]:
            MINE.pop(n)


def test_a_cycle_spanning_more_than_its_period_is_split():
    """A stream that breaks its schedule (the same beacon twice within one period, a stretch of ranges longer
    than the period inside one cycle index after a clock jump) gives cycles of distinct beacons spanning
    less than the period."""
    sched = FiringSchedule(0.4, learn_s=0.4)
    seq = [(0.00, "B1"), (0.05, "B2"), (0.10, "B3"), (0.41, "B1"), (0.46, "B2"),   # learning + one cycle
           (0.50, "B3"), (0.52, "B2"), (0.55, "B4")]                               # B2 twice in one period
    cycles = [c for t, b in seq for c in sched.add(t, b, 1.0)] + sched.flush()
    for cyc in cycles:
        names = [c[1] for c in cyc]
        assert len(set(names)) == len(names)
        assert max(c[3] for c in cyc) - min(c[3] for c in cyc) < 0.4
    assert sched.splits >= 1 and sum(len(c) for c in cycles) == len(seq)


# --------------------------------------------------------------------------- 2. compensation from the filter
def _solver(**kw):
    p = dict(z=-0.75, z_sd=0.0, firing_period=0.4, speed_of_sound=C, refine_iterations=3, motion_compensation=True)
    p.update(kw)
    return OlsTrilateration(OlsParams(**p), BuildContext(layout=INS, beacons=MINE, sensor="abps"))


def _belief(t, v, p, sd_v=1e-3, late=0.0):
    """The filter's belief at t + late: position p (the receiver: no lever arm here), velocity v."""
    x = np.zeros(16)
    x[0:3] = p
    x[3:6] = v
    x[6] = 1.0
    P = np.eye(16) * 1e-2
    P[3:6, 3:6] = np.eye(3) * sd_v ** 2
    return Belief(t + late, x, P=P)


def test_every_cycle_is_compensated_with_the_filter_velocity_also_after_a_failed_fix():
    """Finding 2: an accelerating vehicle (1.2 m/s, 0.3 m/s^2), noise-free ranges; the solver reads the
    belief (the true velocity at the time asked) and its fixes equal the true receiver position at the
    fix's time (to the second-order term of the acceleration within a cycle, a dt^2 / 2 < 6 mm), from the
    first cycle on and right after a refused cycle (3 ranges, one 1 m long: inconsistent, nothing to drop).
    Without compensation the same fixes are several times worse (the unknown motion, weighted as
    correlated range errors, makes them less wrong than a plain fix, not exact)."""
    a = np.array([0.3, 0.05, 0.0])
    v0 = np.array([1.2, 0.1, 0.0])
    route = lambda t: np.array([6.0, 1.2, -0.75]) + v0 * t + 0.5 * a * t * t      # noqa: E731
    stream = firings(route, list(MINE), n_cycles=12, t0=0.0)
    bad_cycle = 5

    def run(compensate):
        s = _solver(motion_compensation=compensate)
        assert isinstance(s, ReadsBelief)
        asked = []
        s.bind_belief(lambda t: asked.append(t) or _belief(t, v0 + a * t, route(t) + [0.3, -0.2, 0.0]))
        fixes = []
        for t, b, r, n in stream:
            if (n == bad_cycle and b not in ("B1", "B2", "B3")) or (n == bad_cycle - 1 and b > "B4"):
                continue                                   # only B1-B3 within a period around cycle 5
            r = r + (1.0 if (n == bad_cycle and b == "B2") else 0.0)
            fixes += [(n, f) for f in s.feed(Message(t, "abps", (b, r)))]
        fixes += [(None, f) for f in s.flush()]
        return s, fixes, asked

    s, fixes, asked = run(True)
    assert s.counters["compensated"] == len(asked) == s.counters["cycles"] - s.counters["too_few_beacons"] >= 11
    errs = [np.linalg.norm(f.value[:2] - route(f.t)[:2]) for _, f in fixes]
    assert len(fixes) >= 10 and max(errs) < 6e-3 and np.median(errs) < 2e-3
    assert s.counters["fixes"] == len(fixes) and s.counters["inconsistent"] == 1
    after = [e for (n, _), e in zip(fixes, errs) if n is not None and n > bad_cycle]
    assert after and after[0] < 6e-3                       # the cycle after the refused one: compensated
    _, fixes_off, _ = run(False)
    errs_off = [np.linalg.norm(f.value[:2] - route(f.t)[:2]) for _, f in fixes_off]
    assert np.median(errs_off) > 3 * np.median(errs)


def test_a_belief_later_than_the_cycle_gives_a_fix_with_its_age():
    """Inputs already integrated past the cycle's mean time (no input batching): the belief comes back later;
    the fix is stamped at the belief's time with the age as a 10th value and is of the position at t - age."""
    v = np.array([1.0, 0.0, 0.0])
    route = lambda t: np.array([6.0, 1.2, -0.75]) + v * t                         # noqa: E731
    s = _solver()
    s.bind_belief(lambda t: _belief(t, v, route(t + 0.12), late=0.12))
    fixes = [f for t, b, r, _ in firings(route, list(MINE), n_cycles=6, t0=0.0)
             for f in s.feed(Message(t, "abps", (b, r)))]
    assert fixes and all(f.age == pytest.approx(0.12) for f in fixes)
    for f in fixes:
        assert np.linalg.norm(f.value[:2] - route(f.t - f.age)[:2]) < 1e-3


# --------------------------------------------------------------------------- 3. honest covariance
def test_fix_covariance_covers_noise_geometry_and_compensation_error():
    """Finding 3, over 1000 seeded cycles at random places in the drift: the velocity used for the
    compensation is off by dv ~ N(0, P_v) (0.25 m/s sd: a poor belief), ranges have 5 cm noise. The fixes'
    horizontal NEES against truth has mean ~2 (its dof) and ~95% inside the 95% bound; the covariance of
    range noise and geometry alone (no compensation term) is overconfident."""
    rng = np.random.default_rng(11)
    B = np.array(list(MINE.values()))
    sd_v, sigma = 0.25, 0.05
    Pv = np.diag([sd_v ** 2, sd_v ** 2, 0.0])
    nees, nees_naive = [], []
    for _ in range(1000):
        x = np.array([rng.uniform(3, 27), rng.uniform(0.5, 2.5), -0.75])
        near = B[np.argsort(np.linalg.norm(B - x, axis=1))[:4]]
        dt = np.linspace(-0.15, 0.15, 4)
        dv = rng.normal(0, sd_v, 3) * [1, 1, 0]
        # ranges taken at dt from the receiver moving at v; compensated with v + dv: the beacons shift by -(v+dv) dt,
        # i.e. relative to the truth by -dv dt
        r = np.linalg.norm(x - (near - dv * dt[:, None]), axis=1) + rng.normal(0, sigma, 4)
        kw = dict(dim=2, z=-0.75, sigma=sigma, refine=3, offsets=dt)
        pos, cov, _ = trilaterate(near, r, velocity_cov=Pv, **kw)
        pos0, cov0, _ = trilaterate(near, r, **kw)
        e = pos[:2] - x[:2]
        nees.append(e @ np.linalg.solve(cov[:2, :2], e))
        e0 = pos0[:2] - x[:2]
        nees_naive.append(e0 @ np.linalg.solve(cov0[:2, :2], e0))
    nees = np.array(nees)
    assert 1.8 < nees.mean() < 2.2
    assert 0.93 < np.mean(nees < 5.991) < 0.97
    assert np.mean(nees_naive) > 1.25 * nees.mean()


def test_uncompensated_fixes_claim_the_motion_they_did_not_remove():
    """Finding 3 (errors of 0.26 m reported with 5 cm sd and accepted): a vehicle at 1.0-1.5 m/s, 5 cm range
    noise, compensation off; each cycle's fix covariance takes the unknown motion (prior_speed_sd) as
    correlated range errors, so over 10 seeded drives the horizontal NEES of the fixes stays at or under
    its dof and no error exceeds 4 of its sd; with a covariance of noise and geometry only it would not."""
    nees, worst = [], 0.0
    for seed in range(10):
        rng = np.random.default_rng(seed)
        v = np.array([1.0 + 0.05 * seed, 0.15 * (-1) ** seed, 0.0])
        route = lambda t: np.array([3.0, 1.4, -0.75]) + v * t                     # noqa: E731
        s = _solver(motion_compensation=False, range_sd=0.05, max_outliers=2)
        for t, b, r, _ in firings(route, list(MINE), n_cycles=40, t0=0.0):
            for f in s.feed(Message(t, "abps", (b, r + rng.normal(0, 0.05)))):
                pos, cov = f.value, f.cov
                e = pos[:2] - route(f.t)[:2]
                nees.append(float(e @ np.linalg.solve(cov[:2, :2], e)))
                worst = max(worst, float(np.max(np.abs(e) / np.sqrt(np.diag(cov)[:2]))))
    assert len(nees) > 300 and np.mean(nees) < 2.2 and worst < 4.0


def test_weighted_fix_equals_scipy_least_squares_with_the_same_range_covariance():
    """The Gauss-Newton fix with correlated range errors is the minimiser of the whitened range residuals:
    scipy.optimize.least_squares on r^T Sigma^-1 r (Sigma at the solution, fixed) finds the same point."""
    rng = np.random.default_rng(5)
    B = np.array(list(MINE.values()))[1:6]
    x = np.array([12.0, 1.7, -0.75])
    dt = np.array([-0.12, -0.06, 0.0, 0.06, 0.12])
    Pv = np.diag([0.04, 0.01, 0.0])
    r = np.linalg.norm(B - x, axis=1) + rng.normal(0, 0.05, 5)
    pos, cov, info = trilaterate(B, r, dim=2, z=-0.75, sigma=0.05, refine=8, offsets=dt, velocity_cov=Pv)
    U = (pos - B) / np.linalg.norm(pos - B, axis=1)[:, None]
    G = U * dt[:, None]
    S = 0.05 ** 2 * np.eye(5) + G @ Pv @ G.T
    L = np.linalg.cholesky(S)
    f = lambda p: np.linalg.solve(L, r - np.linalg.norm(np.r_[p, -0.75] - B, axis=1))   # noqa: E731
    ref = least_squares(f, x[:2] + 0.3, xtol=1e-14, ftol=1e-14).x
    # Sigma here is taken at the fix, in trilaterate at its last iterate's sight lines: the two weightings differ
    # by ~1e-5 relative (their chi2 by 3e-6), which moves the minimum by ~5e-5 of the fix's sd (measured, the same
    # with scipy 1.14 and 1.17); 1e-3 sd is that with 20x room, far inside the fix's own scatter and far above
    # the solver's own stopping point (xtol 1e-14)
    sd = np.sqrt(np.diag(cov)[:2])
    assert np.all(np.abs(pos[:2] - ref) < 1e-3 * sd)
    J = least_squares(f, ref, xtol=1e-14).jac
    np.testing.assert_allclose(cov[:2, :2], np.linalg.inv(J.T @ J), rtol=1e-3)   # that weighting: 4 % of this
    assert info["chi2"] == pytest.approx(float(f(ref) @ f(ref)), rel=1e-4)   # Sigma_r from sight lines ~cm off


# --------------------------------------------------------------------------- 4. consensus
def test_consensus_never_drops_a_good_range_to_keep_a_bad_one():
    """Finding 4: 4 beacons in 2-D, one range 0.3-1.9 m long (a reflection), 600 random places in the drift.
    A good range is never dropped (the leave-one-out of the trial config dropped the good nearest range and
    kept a +1.89 m outlier); when the bad one is dropped the fix is the least-squares fix of the other three
    (scipy.optimize.least_squares started there stays there, to 1% of its sd); an outlier over 1 m is dropped or the fix
    refused in nearly every case (a smaller one along the drift can hide in the geometry: with 2 dof the
    test cannot see it, and the misfit factor widens that fix)."""
    rng = np.random.default_rng(7)
    B = np.array(list(MINE.values()))
    big, big_caught = 0, 0
    for _ in range(600):
        x = np.array([rng.uniform(2, 28), rng.uniform(0.4, 2.6), -0.75])
        near = B[np.argsort(np.linalg.norm(B - x, axis=1))[:4]]
        r = np.linalg.norm(near - x, axis=1) + rng.normal(0, 0.05, 4)
        bad = int(rng.integers(4))
        size = rng.uniform(0.3, 1.9)
        r[bad] += size
        big += size > 1.0
        try:
            pos, cov, info = trilaterate(near, r, dim=2, z=-0.75, sigma=0.05, refine=10,
                                         consistency_probability=0.999, max_outliers=1)
        except NoFix as exc:
            assert exc.reason in ("inconsistent", "ambiguous")
            big_caught += size > 1.0
            continue
        assert set(info["rejected"]) <= {bad}, (x, r, bad, info)
        if info["rejected"]:
            big_caught += size > 1.0
            keep = [i for i in range(4) if i != bad]
            f = lambda p: r[keep] - np.linalg.norm(np.r_[p, -0.75] - near[keep], axis=1)   # noqa: E731
            ref = least_squares(f, pos[:2], xtol=1e-12, ftol=1e-12).x
            assert np.all(np.abs(pos[:2] - ref) < 0.01 * np.sqrt(np.diag(cov)[:2]))   # to 1% of its sd
    assert big > 100 and big_caught >= 0.9 * big


def test_no_fix_when_no_subset_is_consistent():
    """Two reflections among five ranges, only one may be dropped: no fix. (The beacons of one wall are
    collinear: a subset of them and one long range can fit a mirror position across that wall, so the
    reflections are put where no such subset is left.)"""
    B = np.array(list(MINE.values()))[:5]
    x = np.array([10.0, 1.5, -0.75])
    r = np.linalg.norm(B - x, axis=1)
    r[[1, 2]] += [0.8, 1.3]
    with pytest.raises(NoFix) as e:
        trilaterate(B, r, dim=2, z=-0.75, sigma=0.05, refine=3, consistency_probability=0.999, max_outliers=1)
    assert e.value.reason == "inconsistent"
    # beacons around a room (no three in a line): dropping both leaves a good four
    B6 = np.array([[0, 0], [10, 1], [3, 8], [12, 9], [6, -3], [-4, 5]], float)
    B6 = np.c_[B6, np.full(6, -0.9)]
    r6 = np.linalg.norm(B6 - x, axis=1)
    r6[[1, 2]] += [0.8, 1.3]
    pos, _, info = trilaterate(B6, r6, dim=2, z=-0.75, sigma=0.05, refine=3, consistency_probability=0.999,
                               max_outliers=2)
    assert sorted(info["rejected"]) == [1, 2] and np.linalg.norm(pos[:2] - x[:2]) < 1e-6


def test_motion_compensation_needs_a_velocity_block():
    from fusion.api import ConfigError

    with pytest.raises(ConfigError, match="velocity block 'v'"):
        OlsTrilateration(OlsParams(motion_compensation=True),
                         BuildContext(layout=StateLayout.parse("p:3"), beacons=MINE, sensor="abps"))
