"""Solver ``ols_trilateration`` (paper 000 eqs. 17-32): exactness, QR path, covariance, no-fix reasons, cycles."""
from __future__ import annotations

import numpy as np
import pytest

from fusion.api import BuildContext, Fix, MalformedMessage, Message
from fusion_plugins.solvers.ols_trilateration import (NoFix, OlsParams, OlsTrilateration, pack_fix, trilaterate,
                                                      unpack_fix)

# beacons on the walls and roof of a 30 m x 3 m x 1 m excavation (m, NED-like local frame)
MINE = np.array([[0.0, 0.0, -1.0], [6.0, 3.0, -0.9], [12.0, 0.0, -1.0], [18.0, 3.0, -0.95],
                 [24.0, 0.0, -1.0], [30.0, 3.0, -0.9]])
ROOM = np.array([[0.0, 0.0, 0.0], [8.0, 0.0, 2.5], [0.0, 6.0, 1.0], [8.0, 6.0, 0.2], [4.0, 3.0, 3.0]])


def ranges(B, x):
    return np.linalg.norm(np.asarray(B) - x, axis=1)


# --------------------------------------------------------------------------- the pure function
@pytest.mark.parametrize("reference", ["nearest", "first", 2])
def test_exact_recovery_noise_free(reference):
    rng = np.random.default_rng(0)
    for _ in range(20):
        x3 = rng.uniform([1, 1, 0.5], [7, 5, 2.5])
        pos, cov, info = trilaterate(ROOM, ranges(ROOM, x3), dim=3, reference=reference)
        np.testing.assert_allclose(pos, x3, atol=1e-9)
        assert info["method"] == "ols" and np.abs(info["residuals"]).max() < 1e-9
        x2 = np.r_[rng.uniform([1, 0.3], [29, 2.7]), -0.2]       # mine: receiver height known
        pos, cov, info = trilaterate(MINE[:4], ranges(MINE[:4], x2), dim=2, z=-0.2, reference=reference)
        np.testing.assert_allclose(pos, x2, atol=1e-9)
        assert cov.shape == (3, 3) and cov[2, 2] == 0.0


def test_two_d_beacons_and_minimum_counts():
    B2 = MINE[:3, :2]                                           # 2-D beacons, 3 of them: exactly determined
    x = np.array([10.0, 1.2, 0.0])
    pos, _, info = trilaterate(B2, ranges(np.c_[B2, np.zeros(3)], x), dim=2)
    np.testing.assert_allclose(pos, x, atol=1e-9)
    assert info["dof"] == 1


def test_qr_path_equals_ols_when_well_conditioned():
    x = np.array([3.0, 2.0, 1.5])
    r = ranges(ROOM, x) + np.random.default_rng(1).normal(0, 0.05, len(ROOM))
    a = trilaterate(ROOM, r, dim=3, sigma=0.05)
    b = trilaterate(ROOM, r, dim=3, sigma=0.05, qr_condition=1.0)    # force the QR path
    assert a[2]["method"] == "ols" and b[2]["method"] == "qr"
    np.testing.assert_allclose(b[0], a[0], atol=1e-12)
    np.testing.assert_allclose(b[1], a[1], atol=1e-14)


def test_qr_path_sane_when_ill_conditioned():
    """Beacons nearly coplanar (z spread 10 um): cond(A^T A) ~ 1e11; QR still recovers the truth and
    agrees with an SVD least-squares solution of the same linear model."""
    rng = np.random.default_rng(5)
    B = np.column_stack([rng.uniform(0, 20, 6), rng.uniform(0, 20, 6), 3 + 1e-5 * rng.normal(size=6)])
    x = np.array([7.0, 4.0, 1.0])
    pos, cov, info = trilaterate(B, ranges(B, x), dim=3, reference="first", degenerate_condition=1e15)
    assert info["method"] == "qr" and info["cond"] > 1e10
    np.testing.assert_allclose(pos, x, atol=1e-6)
    A = B[1:] - B[0]
    b = 0.5 * (ranges(B, x)[0] ** 2 - ranges(B, x)[1:] ** 2 + np.sum(A * A, axis=1))
    np.testing.assert_allclose(pos, np.linalg.lstsq(A, b, rcond=None)[0] + B[0], atol=1e-6)
    assert np.all(np.isfinite(cov)) and np.sqrt(cov[2, 2]) > 1e3 * np.sqrt(cov[0, 0])   # z barely observable


@pytest.mark.parametrize("dim,B,x,refine", [
    (2, MINE, np.array([14.0, 1.0, -0.1]), 0),
    (2, MINE[:4], np.array([8.0, 2.5, -0.1]), 0),
    (3, ROOM, np.array([3.0, 2.0, 1.5]), 0),
    (2, MINE, np.array([14.0, 1.0, -0.1]), 3),
    (3, ROOM, np.array([3.0, 2.0, 1.5]), 3),
])
def test_covariance_matches_monte_carlo(dim, B, x, refine):
    """2000 seeded noisy cycles: the sample covariance of the fixes matches the predicted one (first
    order, sigma small against the geometry)."""
    rng = np.random.default_rng(42 + dim + refine)
    sigma, n = 0.01, 2000
    r0 = ranges(B, x)
    fixes = np.array([trilaterate(B, r0 + rng.normal(0, sigma, len(r0)), dim=dim, z=x[2], sigma=sigma,
                                  refine=refine)[0] for _ in range(n)])
    _, cov, _ = trilaterate(B, r0, dim=dim, z=x[2], sigma=sigma, refine=refine)
    S = np.cov(fixes[:, :dim].T)
    P = cov[:dim, :dim]
    sd = np.sqrt(np.diag(P))
    # sample covariance: relative sd of a variance estimate ~ sqrt(2/n) = 3%
    np.testing.assert_allclose(np.diag(S), np.diag(P), rtol=0.12)
    np.testing.assert_allclose(S, P, atol=0.12 * np.outer(sd, sd).max())
    np.testing.assert_allclose(fixes[:, :dim].mean(axis=0), x[:dim], atol=4 * sd.max() / np.sqrt(n) + 1e-4)


def test_gauss_newton_is_never_worse_than_ols():
    x = np.array([14.0, 1.0, -0.1])
    a = trilaterate(MINE, ranges(MINE, x), dim=2, z=-0.1, sigma=0.05)[1]
    b = trilaterate(MINE, ranges(MINE, x), dim=2, z=-0.1, sigma=0.05, refine=2)[1]
    assert np.all(np.linalg.eigvalsh(a[:2, :2] - b[:2, :2]) > -1e-12)    # (J^T J)^-1 is the bound


def test_too_few_and_degenerate():
    x = np.array([5.0, 1.0, 0.0])
    with pytest.raises(NoFix) as e:
        trilaterate(MINE[:2], ranges(MINE[:2], x), dim=2)
    assert e.value.reason == "too_few_beacons"
    with pytest.raises(NoFix) as e:
        trilaterate(ROOM[:3], ranges(ROOM[:3], x), dim=3)
    assert e.value.reason == "too_few_beacons"
    line = np.array([[0.0, 0.0, -1.0], [10.0, 0.0, -1.0], [20.0, 0.0, -1.0], [30.0, 0.0, -1.0]])
    with pytest.raises(NoFix) as e:                             # collinear in the plane
        trilaterate(line, ranges(line, x), dim=2)
    assert e.value.reason == "degenerate"
    flat = np.c_[ROOM[:, :2], np.zeros(len(ROOM))]
    with pytest.raises(NoFix) as e:                             # coplanar for a 3-D fix
        trilaterate(flat, ranges(flat, x), dim=3)
    assert e.value.reason == "degenerate"
    with pytest.raises(ValueError, match="shape|expected"):
        trilaterate(ROOM, np.ones(3))


def test_outlier_removed_or_refused():
    rng = np.random.default_rng(3)
    x = np.array([14.0, 1.0, -0.1])
    r = ranges(MINE, x) + rng.normal(0, 0.05, len(MINE))
    r[3] += 1.2                                                 # a reflected, longer path
    kw = dict(dim=2, z=-0.1, sigma=0.05, consistency_probability=0.999)
    pos, _, info = trilaterate(MINE, r, **kw)
    assert info["rejected"] == [3] and info["used"] == [0, 1, 2, 4, 5]
    assert np.linalg.norm(pos[:2] - x[:2]) < 0.2
    pos_off, _, info_off = trilaterate(MINE, r, dim=2, z=-0.1, sigma=0.05)   # test off: outlier kept
    assert info_off["rejected"] == [] and np.linalg.norm(pos_off[:2] - x[:2]) > np.linalg.norm(pos[:2] - x[:2])
    r3 = ranges(MINE[:3], x)
    r3[1] += 1.0                                                # 3 beacons in 2-D: detectable, not removable
    with pytest.raises(NoFix) as e:
        trilaterate(MINE[:3], r3, **kw)
    assert e.value.reason == "inconsistent"


def test_pack_unpack_roundtrip():
    pos = np.array([1.0, 2.0, 3.0])
    A = np.random.default_rng(0).normal(size=(3, 3))
    cov = A @ A.T
    vals = pack_fix(pos, cov)
    assert len(vals) == 9 and all(isinstance(v, float) for v in vals)
    p2, c2 = unpack_fix(vals)
    np.testing.assert_array_equal(p2, pos)
    np.testing.assert_allclose(c2, cov)


# --------------------------------------------------------------------------- the preprocessor
def solver(**kw) -> OlsTrilateration:
    beacons = {f"B{i + 1}": b for i, b in enumerate(MINE)}
    return OlsTrilateration(OlsParams(**kw), BuildContext(beacons=beacons, sensor="abps"))


def cycle_msgs(x, t0, names, spacing=0.02, bump=None):
    out = []
    for j, n in enumerate(names):
        r = float(np.linalg.norm(MINE[int(n[1:]) - 1] - x)) + (bump.get(n, 0.0) if bump else 0.0)
        out.append(Message(t0 + j * spacing, "abps", (n, r), line=j + 1))
    return out


def test_registered():
    from fusion.registry import default_registry

    assert default_registry().get("solver", "ols_trilateration") is OlsTrilateration


def test_feed_gathers_cycles_and_emits_fixes():
    s = solver(z=-0.1, beacons=["B1", "B2", "B3", "B4", "B5"], firing_period=0.4)
    x = np.array([10.0, 1.5, -0.1])
    msgs = cycle_msgs(x, 0.0, ["B1", "B2", "B3", "B4", "B5"])
    outs = [o for m in msgs for o in s.feed(m)]
    assert len(outs) == 1 and s.counters["fixes"] == 1          # closed at once: every expected beacon heard
    fix = outs[0]
    assert isinstance(fix, Fix) and fix.sensor == "abps" and fix.value.shape == (3,) and fix.age == 0.0
    assert fix.t == pytest.approx(0.04)                          # mean time of the ranges
    assert fix.used == ("B1", "B2", "B3", "B4", "B5")
    pos, cov = fix.value, fix.cov
    np.testing.assert_allclose(pos, x, atol=1e-9)
    assert cov[2, 2] == pytest.approx(0.1**2) and np.all(np.linalg.eigvalsh(cov) > 0)
    # a beacon twice within one firing period breaks the schedule: the cycle is split there; the last,
    # incomplete one comes out of flush()
    s = solver(z=-0.1, firing_period=0.4, beacons=["B2", "B3", "B4", "B5"])
    assert len([o for m in cycle_msgs(x, 0.0, ["B2", "B3", "B4", "B5"]) for o in s.feed(m)]) == 1
    outs = [o for m in cycle_msgs(x, 1.0, ["B2", "B3", "B4", "B2", "B3", "B4"]) for o in s.feed(m)]
    assert len(outs) == 1 and outs[0].t == pytest.approx(1.02)
    outs = s.flush()
    assert len(outs) == 1 and s.counters["fixes"] == 3 and s.flush() == []
    assert s.schedule.splits == 1


def test_no_fix_reasons_are_counted_with_events():
    s = solver(z=-0.1, firing_period=0.4)
    x = np.array([10.0, 1.5, -0.1])
    outs = [o for m in cycle_msgs(x, 0.0, ["B1", "B2"]) + cycle_msgs(x, 1.0, ["B3"]) for o in s.feed(m)]
    # the B3 cycle closes at once too: its slot is after the last one heard before (close_at_last_slot)
    assert outs == [] and s.counters["too_few_beacons"] == 2
    assert s.events[-1].kind == "no_fix" and "too_few_beacons" in s.events[-1].detail
    line = {"A": np.array([0.0, 0.0, -1.0]), "B": np.array([10.0, 0.0, -1.0]), "C": np.array([20.0, 0.0, -1.0])}
    s2 = OlsTrilateration(OlsParams(firing_period=0.4), BuildContext(beacons=line, sensor="abps"))
    for n, b in line.items():
        assert s2.feed(Message(0.0, "abps", (n, float(np.linalg.norm(b - x))))) == []
    assert s2.counters["degenerate"] == 1 and s2.events[-1].kind == "no_fix"
    s3 = solver(z=-0.1, firing_period=0.4)                       # 3 beacons, one 1 m off: refused
    outs = [o for m in cycle_msgs(x, 0.0, ["B1", "B2", "B3"], bump={"B2": 1.0}) for o in s3.feed(m)] + s3.flush()
    assert outs == [] and s3.counters["inconsistent"] == 1


def test_outlier_dropped_in_a_redundant_cycle():
    s = solver(z=-0.1, firing_period=0.4)
    x = np.array([14.0, 1.0, -0.1])
    msgs = cycle_msgs(x, 0.0, ["B1", "B2", "B3", "B4", "B5", "B6"], bump={"B4": 1.5})
    outs = [o for m in msgs for o in s.feed(m)]
    assert len(outs) == 1 and s.counters["outliers_removed"] == 1
    assert any(e.kind == "rejected" and "B4" in e.detail for e in s.events)
    np.testing.assert_allclose(outs[0].value, x, atol=1e-9)
    assert "B4" not in outs[0].used


def test_bad_messages():
    s = solver()
    for vals in [("B9", 3.0), ("B1",), ("B1", float("nan")), ("B1", -1.0), (3.0, 2.0), ("B1", "x")]:
        with pytest.raises(MalformedMessage):
            s.feed(Message(0.0, "abps", vals))
    assert s.counters["unknown_beacon"] == 2
    from fusion.api import ConfigError
    with pytest.raises(ConfigError, match="unknown beacon"):
        solver(beacons=["B1", "X"])
    with pytest.raises(ConfigError, match="min_beacons"):
        solver(dim=3, min_beacons=3)
