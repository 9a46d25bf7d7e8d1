"""fusion.metrics and fusion.consistency against independent references (hand RMSE, scipy Rotation/Slerp,
seeded Gaussian samples, scipy.stats.chi2)."""
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp
from scipy.stats import chi2

from fusion.api import Belief, Estimate, Message, StateLayout
from fusion.consistency import ChiSquareStat, chi2_interval, nees
from fusion.metrics import ErrorTracker, Truth, attitude_error_deg

NAMES3 = ("px", "py", "pz", "vx", "vy", "vz", "qw", "qx", "qy", "qz")


def truth_messages(ts, rows, names):
    return [Message(float(t), "truth", tuple(float(v) for v in r)) for t, r in zip(ts, rows)]


def est(t, x, P, reason="update", sensor="uwb"):
    return Estimate(t, Belief(t, np.asarray(x, float), P=np.asarray(P, float)), reason, sensor)


# --------------------------------------------------------------------------- Truth
def test_interpolation_exact_for_linear_truth():
    ts = np.arange(0.0, 10.0, 0.1)
    rows = np.stack([1.0 + 2.0 * ts, -3.0 * ts, 0.5 + 0 * ts, 2.0 + 0 * ts], axis=1)
    msgs = truth_messages(ts, rows, "px py vx vy".split())
    msgs.insert(5, Message(0.33, "uwb", (1.0,)))          # other sensors are ignored
    truth = Truth.from_messages(msgs[::-1], "px py vx vy".split())  # order does not matter
    assert len(truth) == ts.size
    for t in (0.0, 0.05, 1.2345, 5.55, 9.9):
        got = truth.at(t)
        assert got is not None
        assert got["px"] == pytest.approx(1.0 + 2.0 * t, abs=1e-12)
        assert got["py"] == pytest.approx(-3.0 * t, abs=1e-12)
        assert got["vx"] == pytest.approx(0.5) and got["vy"] == pytest.approx(2.0)


def test_none_outside_span_by_more_than_half_period():
    ts = np.arange(0.0, 1.0001, 0.1)
    truth = Truth.from_messages(truth_messages(ts, ts[:, None], ["px"]), ["px"])
    assert truth.at(-0.04)["px"] == pytest.approx(0.0)      # within half a period: nearest sample
    assert truth.at(1.04)["px"] == pytest.approx(1.0)
    assert truth.at(-0.06) is None
    assert truth.at(1.06) is None
    assert Truth.from_messages([], ["px"]).at(0.0) is None


def test_gap_in_truth_gives_none():
    ts = np.r_[np.arange(0, 1, 0.1), np.arange(5, 6, 0.1)]
    truth = Truth.from_messages(truth_messages(ts, ts[:, None], ["px"]), ["px"])
    assert truth.at(3.0) is None
    assert truth.at(0.95)["px"] == pytest.approx(0.95)       # near the gap's edge: still defined


def test_malformed_truth_rows_are_skipped():
    msgs = [Message(0.0, "truth", (1.0, 2.0)), Message(0.1, "truth", (1.0,)), Message(0.2, "truth", ("B1", 1.0))]
    truth = Truth.from_messages(msgs, ["px", "py"])
    assert len(truth) == 1 and truth.skipped == 2
    with pytest.raises(ValueError, match="fields truth"):
        Truth.from_messages(msgs, [])


def test_quaternion_interpolation_matches_scipy_slerp():
    rng = np.random.default_rng(1)
    r = Rotation.random(2, random_state=rng)
    key = Rotation.from_quat([r[0].as_quat(), (r[0] * Rotation.from_rotvec([0.3, -0.2, 0.5])).as_quat()])
    q = key.as_quat(scalar_first=True)
    q[1] *= -1.0                                              # the sign of a truth quaternion is irrelevant
    truth = Truth.from_messages(truth_messages([0.0, 1.0], q, ["qw", "qx", "qy", "qz"]), ["qw", "qx", "qy", "qz"])
    ref = Slerp([0.0, 1.0], key)
    for f in (0.1, 0.37, 0.5, 0.9):
        got = truth.at(f)
        qg = np.array([got[k] for k in ("qw", "qx", "qy", "qz")])
        assert np.linalg.norm(qg) == pytest.approx(1.0)
        # Slerp is closed form (no iteration) and the angle is taken by atan2, exact near 0: rounding only,
        # measured ~1e-14 deg; 1e-9 deg is room for any numpy and scipy, far below a wrong interpolation
        assert attitude_error_deg(ref(f).as_quat(scalar_first=True), qg) < 1e-9


def test_angle_truth_interpolates_across_wrap():
    truth = Truth.from_messages([Message(0.0, "truth", (math.pi - 0.1,)), Message(1.0, "truth", (-math.pi + 0.1,))],
                                ["psi"]).with_angles(["psi"])
    assert abs(truth.at(0.5)["psi"]) == pytest.approx(math.pi)
    assert truth.at(0.25)["psi"] == pytest.approx(math.pi - 0.05)


# --------------------------------------------------------------------------- errors
def test_rmse_by_hand_2d():
    lay = StateLayout.parse("p:2 v:2")
    ts = np.arange(0.0, 5.0, 0.5)
    truth = Truth.from_messages(truth_messages(ts, np.zeros((ts.size, 4)), lay.names), lay.names)
    tr = ErrorTracker(lay, truth)
    rng = np.random.default_rng(0)
    errs = rng.normal(size=(8, 4))
    for k, e in enumerate(errs):
        out = tr.add(est(0.5 * k, e, np.eye(4), reason="output" if k % 2 else "update"))
        assert out["position_m"] == pytest.approx(math.hypot(e[0], e[1]))
        assert out["elements"]["vy"] == pytest.approx(e[3])
    s = tr.summary()
    pos = np.hypot(errs[:, 0], errs[:, 1])
    vel = np.hypot(errs[:, 2], errs[:, 3])
    assert s["errors"]["position_rmse_m"] == pytest.approx(math.sqrt(np.mean(pos ** 2)))
    assert s["errors"]["position_max_m"] == pytest.approx(pos.max())
    assert s["errors"]["velocity_rmse_mps"] == pytest.approx(math.sqrt(np.mean(vel ** 2)))
    assert s["errors"]["element_rmse"]["px"] == pytest.approx(math.sqrt(np.mean(errs[:, 0] ** 2)))
    assert s["errors"]["samples"] == 8
    assert "attitude_rmse_deg" not in s["errors"]             # only the keys that apply
    # NEES with P = I is the squared error norm
    assert s["consistency"]["nees_dof"] == 4
    assert s["consistency"]["nees_mean"] == pytest.approx(np.mean(np.sum(errs ** 2, axis=1)))


def test_nonfinite_estimates_are_left_out_and_counted():
    """A diverged filter's NaN estimates: RMSE, max, element RMSE and samples over the finite ones, the
    others counted in nonfinite_samples (tester3 #15: a finite max next to a None RMSE, samples counting
    the NaN ones); all NaN: no error value at all, the count."""
    lay = StateLayout.parse("p:2 v:2")
    ts = np.arange(0.0, 10.0, 0.5)
    truth = Truth.from_messages(truth_messages(ts, np.zeros((ts.size, 4)), lay.names), lay.names)
    tr = ErrorTracker(lay, truth)
    errs = np.random.default_rng(1).normal(size=(12, 4))
    for k, e in enumerate(errs):
        x = e if k < 7 else e * np.nan if k % 2 else np.r_[e[:3], np.inf]   # diverged from the 8th on
        out = tr.add(est(0.5 * k, x, np.eye(4)))
        assert (out["position_m"] == out["position_m"]) == (k < 7 or k % 2 == 0)  # still given per estimate
    s = tr.summary()
    pos, ok = np.hypot(errs[:, 0], errs[:, 1]), errs[:7]
    assert s["errors"]["position_rmse_m"] == pytest.approx(math.sqrt(np.mean(pos[:7] ** 2)))
    assert s["errors"]["position_max_m"] == pytest.approx(pos[:7].max())
    assert s["errors"]["velocity_rmse_mps"] == pytest.approx(math.sqrt(np.mean(np.hypot(ok[:, 2], ok[:, 3]) ** 2)))
    assert s["errors"]["element_rmse"]["px"] == pytest.approx(math.sqrt(np.mean(ok[:, 0] ** 2)))
    assert s["errors"]["samples"] == 7 and s["errors"]["nonfinite_samples"] == 5
    assert s["consistency"]["nees_samples"] == 7 and s["consistency"]["nees_skipped"] == 5
    tr = ErrorTracker(lay, truth)
    tr.add(est(0.0, [np.nan] * 4, np.eye(4)))
    assert tr.summary()["errors"] == {"samples": 0, "nonfinite_samples": 1}
    tr = ErrorTracker(lay, truth)
    tr.add(est(0.0, [1.0, 0.0, 0.0, 0.0], np.eye(4)))
    assert "nonfinite_samples" not in tr.summary()["errors"]        # only when there are any


def test_settle_and_reasons_and_no_truth():
    lay = StateLayout.parse("p:2")
    ts = np.arange(0.0, 10.0, 1.0)
    truth = Truth.from_messages(truth_messages(ts, np.zeros((10, 2)), lay.names), lay.names)
    tr = ErrorTracker(lay, truth, settle_s=2.0)
    for t in range(10):
        tr.add(est(float(t), [100.0 if t < 2 else 1.0, 0.0], np.eye(2)))
    assert tr.summary()["errors"]["position_max_m"] == pytest.approx(1.0)
    assert tr.summary()["errors"]["samples"] == 8
    tr = ErrorTracker(lay, truth, reasons={"output"})
    assert tr.add(est(1.0, [1.0, 0.0], np.eye(2), reason="update")) is None
    assert tr.add(est(20.0, [1.0, 0.0], np.eye(2), reason="output")) is None   # outside truth
    tr = ErrorTracker(lay, None)
    assert tr.add(est(1.0, [1.0, 0.0], np.eye(2))) is None
    s = tr.summary()
    assert s["errors"] == {} and "nees_mean" not in s["consistency"]


def test_attitude_error_of_known_rotation():
    lay = StateLayout.parse("p:3 v:3 q:4 ba:3")
    rng = np.random.default_rng(7)
    r_true = Rotation.random(random_state=rng)
    names = NAMES3 + ("bax", "bay", "baz")
    row = np.r_[[1, 2, 3], [0, 0, 0], r_true.as_quat(scalar_first=True), [0.01, 0.02, 0.03]]
    truth = Truth.from_messages(truth_messages([0.0, 1.0], [row, row], names), names)
    tr = ErrorTracker(lay, truth)
    for angle_deg, axis in ((5.0, [0, 0, 1]), (30.0, [1, 1, 0]), (179.0, [0.2, -1, 0.4])):
        rv = np.radians(angle_deg) * np.asarray(axis, float) / np.linalg.norm(axis)
        r_est = r_true * Rotation.from_rotvec(rv)
        q_est = -r_est.as_quat(scalar_first=True)              # the antipodal quaternion: same attitude
        x = np.r_[[1, 2, 3], [0, 0, 0], q_est, [0.01, 0.02, 0.03]]
        out = tr.add(est(0.5, x, np.eye(13)))
        ref = (r_true.inv() * r_est).magnitude()
        assert out["attitude_deg"] == pytest.approx(np.degrees(ref), abs=1e-9)
        assert out["attitude_deg"] == pytest.approx(angle_deg, abs=1e-9)
        assert out["position_m"] == pytest.approx(0.0, abs=1e-12)
        assert out["elements"]["bay"] == pytest.approx(0.0, abs=1e-15)
    s = tr.summary()["errors"]
    assert s["attitude_rmse_deg"] == pytest.approx(math.sqrt((5 ** 2 + 30 ** 2 + 179 ** 2) / 3))
    assert s["attitude_max_deg"] == pytest.approx(179.0)
    assert "ba" not in s and "bax" in s["element_rmse"]


def test_angle_block_errors_wrap():
    lay = StateLayout.parse("p:2 psi:1:angle")
    truth = Truth.from_messages(truth_messages([0.0, 1.0], [[0, 0, math.pi - 0.01]] * 2, lay.names), lay.names)
    out = ErrorTracker(lay, truth).add(est(0.5, [0, 0, -math.pi + 0.01], np.eye(3)))
    assert out["elements"]["psi"] == pytest.approx(0.02)


# --------------------------------------------------------------------------- consistency
def random_spd(rng, n, scale=1.0):
    A = rng.normal(size=(n, n)) * scale
    return A @ A.T + 0.1 * scale ** 2 * np.eye(n)


def test_nees_function_matches_solve():
    rng = np.random.default_rng(3)
    P = random_spd(rng, 5)
    e = rng.normal(size=5)
    assert nees(e, P) == pytest.approx(e @ np.linalg.solve(P, e), rel=1e-10)
    assert math.isnan(nees(e, -P))
    assert math.isnan(nees(e * np.nan, P))


def test_chi2_interval_and_stat():
    lo, hi = chi2_interval(3)
    assert lo == pytest.approx(chi2.ppf(0.025, 3)) and hi == pytest.approx(chi2.ppf(0.975, 3))
    st = ChiSquareStat()
    assert st.add(float("nan"), 3) is None and st.skipped == 1 and st.mean is None


def test_nees_of_consistent_gaussian_sample_with_attitude():
    """Errors drawn from the filter's own covariance: NEES mean ~ dof and ~95% inside the interval.
    Attitude errors are drawn as rotation vectors (body frame) and turned into the 4x4 covariance of the
    additive quaternion error by the first-order kinematics dq = 0.5 q (x) [0, dtheta]."""
    lay = StateLayout.parse("p:3 v:3 q:4 bw:3")
    names = NAMES3 + ("bwx", "bwy", "bwz")
    rng = np.random.default_rng(42)
    steps = 1500
    ts = np.arange(steps + 1) * 0.1
    truth_rows = np.zeros((steps + 1, 13))
    rots = Rotation.random(steps + 1, random_state=rng)
    truth_rows[:, 6:10] = rots.as_quat(scalar_first=True)
    truth_rows[:, :3] = rng.normal(size=(steps + 1, 3)) * 10
    truth = Truth.from_messages(truth_messages(ts, truth_rows, names), names)
    tr = ErrorTracker(lay, truth)
    for k in range(steps):
        # 12-dof error covariance over [p v dtheta bw], correlated, attitude small (1e-3 rad)
        C = random_spd(rng, 12)
        C[6:9, :] *= 1e-3
        C[:, 6:9] *= 1e-3
        err = rng.multivariate_normal(np.zeros(12), C)         # x_true - x_est, dtheta: est -> true
        r_true = rots[k]
        r_est = r_true * Rotation.from_rotvec(-err[6:9])        # q_true = q_est (x) exp(dtheta)
        q_est = r_est.as_quat(scalar_first=True)
        w, a, b, c = q_est
        Lq = np.array([[w, -a, -b, -c], [a, w, -c, b], [b, c, w, -a], [c, -b, a, w]])
        G = np.zeros((13, 12))                                  # x_true - x_est = G err (first order)
        G[:6, :6] = np.eye(6)
        G[6:10, 6:9] = 0.5 * Lq[:, 1:]
        G[10:, 9:] = np.eye(3)
        P = G @ C @ G.T + 1e-12 * np.eye(13)
        x_est = np.r_[truth_rows[k, :6] - err[:6], q_est, -err[9:]]
        tr.add(est(ts[k], x_est, P))
    s = tr.summary()["consistency"]
    assert s["nees_dof"] == 12
    assert s["nees_samples"] == steps and s["nees_skipped"] == 0
    # mean of 1500 chi2(12) samples: sd = sqrt(2*12/1500) = 0.13
    assert s["nees_mean"] == pytest.approx(12.0, abs=0.5)
    assert s["nees_in_95_fraction"] == pytest.approx(0.95, abs=0.02)


def test_nees_without_attitude_and_inconsistent_filter():
    lay = StateLayout.parse("p:3 v:3 q:4")
    rng = np.random.default_rng(5)
    row = np.r_[np.zeros(6), 1.0, 0, 0, 0]
    truth = Truth.from_messages(truth_messages([0.0, 1000.0], [row, row], NAMES3), NAMES3)
    ok = ErrorTracker(lay, truth, nees_attitude=False)
    bad = ErrorTracker(lay, truth, nees_attitude=False)
    for k in range(1000):
        C = random_spd(rng, 6)
        e = rng.multivariate_normal(np.zeros(6), C)
        P = np.eye(10)
        P[:6, :6] = C
        x = np.r_[e, 1.0, 0, 0, 0]
        ok.add(est(float(k), x, P))
        P[:6, :6] = C / 4.0                                     # over-confident: NEES ~ 4 dof
        bad.add(est(float(k), x, P))
    assert ok.summary()["consistency"]["nees_dof"] == 6
    assert ok.summary()["consistency"]["nees_mean"] == pytest.approx(6.0, abs=0.4)
    assert bad.summary()["consistency"]["nees_mean"] == pytest.approx(24.0, abs=1.6)
    assert bad.summary()["consistency"]["nees_in_95_fraction"] < 0.5


def test_nis_per_sensor():
    rng = np.random.default_rng(11)
    tr = ErrorTracker(StateLayout.parse("p:2"), None)
    for k in range(4000):
        tr.add_nis("uwb", float(rng.chisquare(1)), 1, t=0.01 * k)
        tr.add_nis("gps", float(rng.chisquare(3)), 3)
    tr.add_nis("gps", float("nan"), 3)
    c = tr.summary()["consistency"]
    assert set(c["nis_mean"]) == {"uwb", "gps"}
    assert c["nis_mean"]["uwb"] == pytest.approx(1.0, abs=0.1)
    assert c["nis_mean"]["gps"] == pytest.approx(3.0, abs=0.15)
    assert c["nis_in_95_fraction"]["gps"] == pytest.approx(0.95, abs=0.015)
    assert c["nis_dof"] == {"gps": 3, "uwb": 1}
    series = tr.nis_series()
    assert set(series) == {"uwb"} and series["uwb"][0].shape == (4000,) and series["uwb"][2] == 1


def test_nis_of_accepted_updates_apart_from_rejected_and_per_dof():
    """tester5 #9: 1-dof arrivals (accepted mean ~1), one 4-dof fix and rejected echoes (NIS ~230) read
    'mean 15.4 on 4 dof' in one running mean; the accepted ones, per dof, are given apart now."""
    rng = np.random.default_rng(5)
    tr = ErrorTracker(StateLayout.parse("p:2"), None)
    ones = rng.chisquare(1, 3000)
    for v in ones:
        tr.add_nis("us", float(v), 1, accepted=True)
    tr.add_nis("us", 2.0, 4, accepted=True)
    for v in 200.0 + 60.0 * rng.random(200):
        tr.add_nis("us", float(v), 1, accepted=False)
    tr.add_nis("fix", 3.0, 2, accepted=True)
    c = tr.summary()["consistency"]
    # the keys of before keep their meaning: every update tried, the largest dof
    assert c["nis_samples"]["us"] == 3201 and c["nis_dof"]["us"] == 4 and c["nis_mean"]["us"] > 10.0
    assert c["nis_accepted_samples"] == {"fix": 1, "us": 3001}
    assert c["nis_accepted_dofs"] == {"fix": [2], "us": [1, 4]}
    assert c["nis_accepted_mean"]["us"] == pytest.approx((ones.sum() + 2.0) / 3001)
    assert c["nis_accepted_mean_per_dof"]["us"] == pytest.approx((ones.sum() + 2.0) / 3004)
    assert c["nis_accepted_mean_per_dof"]["us"] == pytest.approx(1.0, abs=0.06)
    lo, hi = c["nis_accepted_mean_per_dof_95"]["us"]
    assert (lo, hi) == pytest.approx((chi2.ppf(0.025, 3004) / 3004, chi2.ppf(0.975, 3004) / 3004))
    by = c["nis_accepted_by_dof"]
    assert set(by) == {"us"} and by["us"]["1"]["samples"] == 3000 and by["us"]["4"]["mean"] == 2.0
    assert by["us"]["1"]["mean"] == pytest.approx(ones.mean())
    assert c["nis_accepted_in_95_fraction"]["us"] == pytest.approx(0.95, abs=0.015)
    assert c["nis_rejected_samples"] == {"fix": 0, "us": 200} and c["nis_rejected_mean"]["fix"] is None
    assert 200.0 < c["nis_rejected_mean"]["us"] < 260.0


def test_nis_without_accepted_flags_has_the_keys_of_before_only():
    tr = ErrorTracker(StateLayout.parse("p:2"), None)
    tr.add_nis("uwb", 1.0, 1)
    assert set(tr.summary()["consistency"]) == {"nis_mean", "nis_in_95_fraction", "nis_dof", "nis_samples"}
