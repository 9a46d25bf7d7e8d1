"""tdoa_geometric (paper 003 eqs. 1-8): exact on noise-free arrivals from several starts, eq. 8 against a
linear solve, GLS with more than four beacons, the fix covariance against Monte-Carlo scatter, and the
counted reasons for no fix."""
from __future__ import annotations

import numpy as np
import pytest

from fusion import testing
from fusion.api import BuildContext, ConfigError, Fix, MalformedMessage, Message
from fusion_plugins.solvers.tdoa_geometric import NoFix, biorthogonal_step, tdoa_fix

C, T = 340.0, 0.225
LAB = np.array([[0, 0, 0], [2.6, 0, 0], [0, 2.6, 0], [0, 0, 2.6]], float)   # paper 003 fig. 1


def _arrivals(r, B, t0=0.137, sigma=0.0, rng=None, firings=None):
    n = np.arange(len(B)) if firings is None else np.asarray(firings)
    a = t0 + n * T + np.linalg.norm(r - B, axis=1) / C
    if sigma:
        a = a + rng.normal(0.0, sigma, a.shape)
    return a, n


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("start", [None, (2.0, 2.0, 2.0), (0.5, 2.4, 0.5), (0.1, 0.1, 0.1), (1.0, 0.2, 2.2)])
def test_exact_on_noise_free_arrivals(seed, start):
    r = np.random.default_rng(seed).uniform(0.5, 2.5, 3)
    a, n = _arrivals(r, LAB)
    s = LAB.mean(axis=0) if start is None else np.array(start)
    pos, cov, it = tdoa_fix(LAB, a, n, T, C, s, tolerance=1e-12)
    assert np.abs(pos - r).max() < 1e-9
    assert it <= 10


def test_three_or_four_iterations_from_a_nearby_start():
    """The paper: 3 or 4 iterations for convergence (at the mm level, from the previous fix)."""
    r = np.array([1.21, 1.15, 1.36])
    a, n = _arrivals(r, LAB)
    _, _, it = tdoa_fix(LAB, a, n, T, C, r + 0.05, tolerance=1e-4)
    assert it <= 4


def test_biorthogonal_step_is_the_linear_solve():
    rng = np.random.default_rng(1)
    for _ in range(20):
        G, dd = rng.normal(size=(3, 3)), rng.normal(size=3)
        assert np.allclose(biorthogonal_step(G, dd), np.linalg.solve(G, dd), rtol=1e-10, atol=1e-12)


def test_more_beacons_by_least_squares():
    B = np.vstack([LAB, [[2.6, 2.6, 0.0], [2.6, 0.0, 2.6]]])
    r = np.array([1.7, 0.9, 1.2])
    a, n = _arrivals(r, B, firings=[0, 1, 2, 3, 4, 6])     # a missed firing (5) in between
    pos, _, _ = tdoa_fix(B, a, n, T, C, B.mean(axis=0), tolerance=1e-12)
    assert np.abs(pos - r).max() < 1e-9


@pytest.mark.parametrize("B", [LAB, np.vstack([LAB, [[2.6, 2.6, 2.6], [2.6, 2.6, 0.0]]])], ids=["4", "6"])
def test_fix_covariance_matches_monte_carlo(B):
    """Eq. 8 maps arrival-time errors to the position: the reported covariance is the scatter of fixes."""
    rng = np.random.default_rng(7)
    r, sigma, N = np.array([1.2, 1.4, 0.9]), 1e-5, 2000     # small noise: the linearisation holds
    fixes = []
    for _ in range(N):
        a, n = _arrivals(r, B, sigma=sigma, rng=rng)
        fixes.append(tdoa_fix(B, a, n, T, C, r, sigma=sigma)[0])
    S = np.cov(np.array(fixes).T)
    _, cov, _ = tdoa_fix(B, _arrivals(r, B)[0], np.arange(len(B)), T, C, r, sigma=sigma)
    # each variance within ~4 standard errors of a sample variance (sqrt(2/N) = 3.2 %)
    assert np.allclose(np.diag(S), np.diag(cov), rtol=0.13)
    assert np.abs(S - cov).max() < 0.13 * np.diag(cov).max()


def test_degenerate_geometry_gives_no_fix():
    """Beacons in one plane and the robot in it: every u_i lies in the plane, the gradients are coplanar."""
    B = np.array([[0, 0, 0], [2.6, 0, 0], [0, 2.6, 0], [2.6, 2.6, 0]], float)
    r = np.array([1.0, 1.3, 0.0])
    a, n = _arrivals(r, B)
    with pytest.raises(NoFix) as err:
        tdoa_fix(B, a, n, T, C, r)
    assert err.value.reason == "degenerate"


def test_non_convergence_gives_no_fix():
    r = np.array([1.21, 1.15, 1.36])
    a, n = _arrivals(r, LAB)
    with pytest.raises(NoFix) as err:
        tdoa_fix(LAB, a, n, T, C, (2.0, 0.2, 0.2), max_iterations=1)
    assert err.value.reason == "no_convergence"
    with pytest.raises(NoFix):
        tdoa_fix(LAB[:3], a[:3], n[:3], T, C, r)


# --------------------------------------------------------------------------- the preprocessor
def _solver(**params):
    ctx = BuildContext(beacons={f"B{i + 1}": b for i, b in enumerate(LAB)}, sensor="us")
    return testing.build("solver", "tdoa_geometric", params, ctx)


def _messages(r, cycles, t0=0.137, drop=()):
    out, k = [], 0
    for _ in range(cycles):
        for i, b in enumerate(LAB):
            a = t0 + k * T + np.linalg.norm(r - b) / C
            if k not in drop:
                out.append(Message(a, "us", (f"B{i + 1}", a, 11.0)))
            k += 1
    return out


def test_solver_one_fix_per_cycle_with_covariance():
    r = np.array([0.59, 1.14, 0.9])
    s = _solver()
    fixes = [m for msg in _messages(r, 5) for m in s.feed(msg)]
    assert len(fixes) == 5 and s.counters["fixes"] == 5
    for f in fixes:
        assert isinstance(f, Fix) and f.used == ("B1", "B2", "B3", "B4") and f.line is None
        pos, cov = f.value, f.cov
        assert np.abs(pos - r).max() < 1e-8
        assert np.all(np.linalg.eigvalsh(cov) > 0)


def test_solver_counts_missing_beacons_and_initialise_mode():
    r = np.array([1.2, 1.1, 1.3])
    s = _solver()
    out = [m for msg in _messages(r, 3, drop={5}) for m in s.feed(msg)] + s.flush()
    assert len(out) == 2 and s.counters["too_few_beacons"] == 1
    assert any(e.kind == "no_fix" and "too_few_beacons" in e.detail for e in s.events)
    s = _solver(output="initialise")
    msgs = _messages(r, 5)
    out = [m for msg in msgs for m in s.feed(msg)]
    assert out[0].value.shape == (5,) and out[0].cov.shape == (5, 5) and out[0].attitude is None   # [p t T]
    assert out[1:] == msgs[12:]      # one fix (three cycles agree), then the arrivals


def test_initialiser_is_not_placed_by_an_echo():
    """An echo (1 m of extra path) in the first cycle: that fix disagrees with the next; the initial fix is
    the mean of the first two that agree, near the truth."""
    r = np.array([1.2, 1.1, 1.3])
    msgs = _messages(r, 4)
    b, a, rec = msgs[1].values
    msgs[1] = Message(a + 1.0 / C, "us", (b, a + 1.0 / C, rec))
    s = _solver(output="initialise", initialise_agree=2)
    out = [m for msg in msgs for m in s.feed(msg)]
    pos = out[0].value[:3]
    assert np.abs(pos - r).max() < 1e-6 and out[0].t == msgs[11].t
    s1 = _solver(output="initialise", initialise_agree=1)      # without the agreement: placed by the echo
    pos1 = [m for msg in msgs for m in s1.feed(msg)][0].value[:3]
    assert np.linalg.norm(pos1 - r) > 0.2


def test_solver_bad_input():
    s = _solver()
    assert s.feed(Message(1.0, "us", ("B9", 1.0, 3.0), 7)) == []      # counted and reported, not raised
    assert s.feed(Message(1.0, "us", ("B1", "x", 3.0), 8)) == []
    assert s.counters["malformed"] == 2
    assert [e.kind for e in s.events] == ["malformed"] * 2
    assert "line 7: unknown beacon" in s.events[0].detail and "not a number" in s.events[1].detail
    with pytest.raises(ConfigError, match="at least 4 beacons"):
        _solver(beacons=["B1", "B2", "B3"])


def test_initial_state_fix_carries_the_firing_time():
    """The initial fix: position, t = the last firing's time and the period T (exact on exact arrivals),
    observed by arrival_time as a linear fix of p, t and T whose covariance is the fit's: cov(t, T) =
    n_last var(T) + cov(t0, T) of t = t0 + n_last T."""
    from fusion_plugins.solvers.initial_fix import observe_initial, state_fix
    r = np.array([1.2, 1.1, 1.3])
    msgs = _messages(r, 3, t0=0.137)
    s = _solver(output="initialise")
    out = [m for msg in msgs for m in s.feed(msg)]
    v = out[0].value
    assert np.abs(v[:3] - r).max() < 1e-8
    assert v[3] == pytest.approx(0.137 + 11 * T, abs=1e-10)           # the 12th firing (B4 of cycle 3)
    assert v[4] == pytest.approx(T, abs=1e-12)
    proc = testing.build("process", "firing_clock", {})
    ctx = BuildContext(layout=proc.layout, beacons={f"B{i + 1}": b for i, b in enumerate(LAB)})
    obs = observe_initial(out[0], ctx)
    lay = proc.layout
    x = np.zeros(lay.n)
    x[lay["p"]], x[lay["T"]], x[lay["t"]] = r, T, v[3]
    assert obs.z.shape == (5,) and np.allclose(obs.model.h(x), obs.z, atol=1e-8)
    H = obs.model.jacobian(x)
    assert np.array_equal(H @ x, obs.model.h(x))
    assert np.all(np.linalg.eigvalsh(obs.R) > 0)
    assert 1e-6 < np.sqrt(obs.R[4, 4]) < 1e-4                          # 3 cycles of 0.2 ms arrivals: ~20 us
    # the 4-value fix (no period) is still read
    old = state_fix(1.0, r, np.eye(3) * 1e-4, v[3], np.zeros(3), 1e-8)
    assert observe_initial(old, ctx).z.shape == (4,)
    with pytest.raises(MalformedMessage):                              # a message is no typed fix
        observe_initial(Message(1.0, "us", tuple(v.tolist())), ctx)
    with pytest.raises(MalformedMessage, match="4 or 5 finite"):
        observe_initial(Fix(1.0, np.r_[v[:3], np.nan], out[0].cov), ctx)
    with pytest.raises(MalformedMessage, match="5 x 5"):
        observe_initial(Fix(1.0, v, None), ctx)


# --------------------------------------------------------------------------- echoes thrown far, the bound
FAR = np.array([2.37, 2.2, 1.35])     # paper 003 Table I, row 4: the position farthest from the beacons


def test_an_echo_thrown_far_does_not_agree():
    """At the far position 0.7 m of extra path on B1 throws the fix ~8 m out, where its own covariance is
    metres wide: against C_a + C_b it "agreed" with the true fix (statistic ~4 < 11.3); against twice the
    better-determined covariance it does not."""
    from fusion_plugins.solvers.tdoa_geometric import AgreeingFixes

    a, n = _arrivals(FAR, LAB)
    good, cov_g, _ = tdoa_fix(LAB, a, n, T, C, FAR)
    a[0] += 0.7 / C
    bad, cov_b, _ = tdoa_fix(LAB, a, n, T, C, FAR)
    assert np.linalg.norm(bad - FAR) > 5.0 and np.sqrt(np.diag(cov_b)).max() > 2.0
    agree = AgreeingFixes(3)
    assert not agree.agree(bad, cov_b, good, cov_g) and not agree.agree(good, cov_g, bad, cov_b)
    assert agree.agree(good, cov_g, good + 0.5 * np.sqrt(np.diag(cov_g)), cov_g)   # one sd apart: agree


def test_initialiser_is_not_placed_by_an_echo_thrown_far():
    """Three agreeing cycles start the filter; an echo thrown far in the third must restart the count (it
    once averaged in and started the filter metres off with a metres-wide covariance)."""
    msgs = _messages(FAR, 8)
    b, a, rec = msgs[9].values                      # cycle 3, beacon B2? no: index 9 is cycle 3, B2
    b, a, rec = msgs[8].values                      # cycle 3, B1
    msgs[8] = Message(a + 0.7 / C, "us", (b, a + 0.7 / C, rec))
    s = _solver(output="initialise", initialise_agree=3)
    out = [m for msg in msgs for m in s.feed(msg)]
    pos, cov = out[0].value[:3], out[0].cov[:3, :3]
    assert np.abs(pos - FAR).max() < 1e-6
    assert np.sqrt(np.diag(cov)).max() < 0.15         # 3 fixes of 0.2 ms arrivals (~0.18 m each), not metres
    assert out[0].t >= msgs[23].t        # three agreeing cycles after the echo's (3 disagrees with 2 and 4)


def test_stationary_bound_is_the_scatter_of_least_squares():
    """stationary_bound against the scatter of the least-squares estimate of [x y z T t0] from noisy
    arrivals of a standing robot (scipy least_squares: an independent solver), and against the single-fix
    covariance of eq. 8 / N for N cycles when T is known (T's column removed: the same information)."""
    from scipy.optimize import least_squares

    from fusion_plugins.solvers.tdoa_geometric import stationary_bound

    rng = np.random.default_rng(3)
    cycles, sigma, t0 = 6, 2e-5, 0.137
    k = np.arange(4 * cycles)
    Bk = LAB[k % 4]
    clean = t0 + k * T + np.linalg.norm(FAR - Bk, axis=1) / C
    est = []
    for _ in range(600):
        a = clean + rng.normal(0.0, sigma, k.size)
        fun = lambda x: (x[4] + k * x[3] + np.linalg.norm(x[:3] - Bk, axis=1) / C - a) / sigma  # noqa: E731
        est.append(least_squares(fun, np.r_[FAR + 0.01, T, t0], x_scale=[1, 1, 1, 1e-6, 1e-4]).x)
    S = np.cov(np.array(est).T)
    bound = stationary_bound(Bk, FAR, k, C, sigma)
    assert np.allclose(np.diag(S)[:3], np.diag(bound)[:3], rtol=0.2)   # sample variance of 600: +-12 % (2 se)
    # T known: the position block is the one-cycle fix covariance over N cycles
    _, cov1, _ = tdoa_fix(LAB, clean[:4], np.arange(4), T, C, FAR, sigma=sigma)
    d = FAR - Bk
    J = np.column_stack([d / (C * np.linalg.norm(d, axis=1, keepdims=True)), np.ones(k.size)])
    known = np.linalg.inv(J.T @ J / sigma ** 2)[:3, :3]
    assert np.allclose(known, cov1 / cycles, rtol=1e-6)
    assert np.all(np.diag(bound)[:3] >= np.diag(known) * (1 - 1e-9))    # an unknown T never helps
    with pytest.raises(np.linalg.LinAlgError):
        stationary_bound(LAB, FAR, np.arange(4), C, sigma)               # one cycle: T not determined


def test_stationary_fix_uses_every_genuine_arrival_and_drops_echoes():
    """stationary_fix over 10 cycles at the far position with an echo in each of 4 of them: the echoes are
    dropped, the fix is the truth (noise-free), and its covariance is the Cramer-Rao bound of the genuine
    arrivals with T known (the [p, t0] block of sigma^2 (J^T J)^-1), far below a 3-cycle fix's."""
    from fusion_plugins.solvers.stationary_fix import stationary_fix

    k = np.arange(40)
    Bk = LAB[k % 4]
    a = 0.137 + k * T + np.linalg.norm(FAR - Bk, axis=1) / C
    echo = np.zeros(k.size, bool)
    echo[[1, 6, 19, 28]] = True
    a[echo] += np.array([0.4, 1.0, 2.5, 0.7]) / C
    pos, t0, cov, used = stationary_fix(Bk, a, T, C, 2e-4, FAR + np.array([0.2, -0.15, 0.1]),
                                        np.eye(3) * 0.2 ** 2)
    assert np.array_equal(used, ~echo)
    assert np.abs(pos - FAR).max() < 1e-7 and abs(t0 - 0.137) < 1e-9
    d = FAR - Bk[~echo]
    J = np.column_stack([d / (C * np.linalg.norm(d, axis=1, keepdims=True)), np.ones(d.shape[0])])
    assert np.allclose(cov, (2e-4) ** 2 * np.linalg.inv(J.T @ J), rtol=1e-6)
    _, cov1, _ = tdoa_fix(LAB, a[8:12], np.arange(4), T, C, FAR)
    assert np.trace(cov[:3, :3]) < np.trace(cov1) / 5


def test_stationary_initialiser_keeps_the_wait():
    """initialise_stationary: the initial fix after a wait (echoes in the first cycles) carries the
    information of every genuine arrival so far, not of the three agreeing cycles only; same message."""
    msgs = _messages(FAR, 9)
    for j in (1, 6, 10, 13):                       # echoes in cycles 1-4: the agreeing run starts at 5
        b, a, rec = msgs[j].values
        msgs[j] = Message(a + 1.0 / C, "us", (b, a + 1.0 / C, rec))
    plain = _solver(output="initialise")
    batch = _solver(output="initialise", initialise_stationary=True)
    f0 = [m for msg in msgs for m in plain.feed(msg)][0]
    f1 = [m for msg in msgs for m in batch.feed(msg)][0]
    assert f0.t == f1.t and f0.value.shape == f1.value.shape == (5,) and f1.cov.shape == (5, 5)
    p0, c0 = f0.value[:3], f0.cov[:3, :3]
    p1, c1 = f1.value[:3], f1.cov[:3, :3]
    assert np.abs(p1 - FAR).max() < 1e-6
    assert np.trace(c1) < 0.6 * np.trace(c0)       # 28 genuine arrivals against 12
    assert abs(f1.value[3] - f0.value[3]) < 1e-6  # the same latest firing time (noise-free)


# --------------------------------------------------------------------------- a period off its nominal value
@pytest.mark.parametrize("true_T", [0.2251, 0.2255, 0.226, 0.2239])
@pytest.mark.parametrize("stationary", [False, True])
def test_initial_fix_with_the_period_off_its_nominal_value(true_T, stationary):
    """Beacons whose period is up to 0.5 % off period_s (a ceramic resonator's tolerance). Fixed
    at period_s the three agreeing cycles all put the robot ~0.5 m off (0.2 %) with an sd of ~45 mm; the
    period estimated from them starts it right, T in the fix within 3 sd of the truth, the position error
    within 3 sd of its covariance (0.2 ms noise; 10 seeds)."""
    rng = np.random.default_rng(7)
    r = np.array([1.5, 1.5, 1.5])
    for _ in range(10):
        msgs, k = [], 0
        for _ in range(8 if stationary else 3):
            for i, b in enumerate(LAB):
                a = 0.137 + k * true_T + np.linalg.norm(r - b) / C + rng.normal(0.0, 2e-4)
                msgs.append(Message(a, "us", (f"B{i + 1}", a, 11.0)))
                k += 1
        s = _solver(output="initialise", initialise_stationary=stationary)
        fix = [m for msg in msgs for m in s.feed(msg)][0]
        v, P = fix.value, fix.cov
        assert v.shape == (5,)
        e = v[:3] - r
        assert float(e @ np.linalg.solve(P[:3, :3], e)) < 16.3                 # chi2(3) 0.999
        assert abs(v[4] - true_T) < 3.5 * np.sqrt(P[4, 4])
        j = next(i for i, m in enumerate(msgs) if m.t == fix.t)                   # the latest firing
        assert abs(v[3] - (0.137 + j * true_T)) < 3.5 * np.sqrt(P[3, 3])
        assert np.linalg.norm(e) < 0.2                                        # not 0.5-1 m


def test_period_fix_is_least_squares_of_arrivals_against_firing_numbers():
    """period_fix against scipy least_squares on [p, t0, T] (an independent solver), and its covariance against
    stationary_bound (the same information)."""
    from scipy.optimize import least_squares

    from fusion_plugins.solvers.stationary_fix import period_fix
    from fusion_plugins.solvers.tdoa_geometric import stationary_bound

    rng = np.random.default_rng(2)
    k = np.arange(12)
    Bk = LAB[k % 4]
    true_T = 0.2257
    a = 1000.137 + k * true_T + np.linalg.norm(FAR - Bk, axis=1) / C + rng.normal(0.0, 2e-4, k.size)
    pos, t0, Tf, cov = period_fix(Bk, a, T, C, 2e-4, FAR + 0.3)
    fun = lambda x: x[4] + k * x[3] + np.linalg.norm(x[:3] - Bk, axis=1) / C - (a - 1000.0)  # noqa: E731
    fit = least_squares(fun, np.r_[FAR, T, 0.137], x_scale=[1, 1, 1, 1e-5, 1e-4], xtol=1e-15, ftol=1e-15,
                        gtol=1e-15)
    ours = np.r_[pos, Tf, t0 - 1000.0]
    # Two solvers agree only as far as the conditioning (cond(J) ~ 2e4 here) and the reference's stopping rule
    # allow, which is far below the estimate's own standard deviation: 1e-4 sd is the same answer (the
    # differences seen are ~3e-6 sd). cov is ordered [x y z t0 T], ours [x y z T t0].
    sd = np.sqrt(np.diag(cov))[[0, 1, 2, 4, 3]]
    assert np.all(np.abs(ours - fit.x) < 1e-4 * sd)
    # Optimality without the reference's digits: the cost is not above the reference's (to its ftol), and
    # the normal equations J^T r = 0 hold to far below double rounding times the conditioning (~1e-11).
    assert 0.5 * np.sum(fun(ours) ** 2) <= fit.cost * (1 + 1e-9)
    assert np.linalg.norm(fit.jac.T @ fun(ours)) < 1e-8 * np.linalg.norm(fit.jac) * np.linalg.norm(fun(ours))
    bound = stationary_bound(Bk, pos, k, C, 2e-4)           # order [x y z T t0]
    assert np.allclose(cov[:3, :3], bound[:3, :3], rtol=1e-6)
    assert cov[4, 4] == pytest.approx(bound[3, 3], rel=1e-6) and cov[3, 3] == pytest.approx(bound[4, 4], rel=1e-6)
    with pytest.raises(np.linalg.LinAlgError):
        period_fix(LAB, a[:4], T, C, 2e-4, FAR)                # one cycle: T not determined
