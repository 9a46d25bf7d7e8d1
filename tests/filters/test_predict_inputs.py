"""Batched input integration (Filter.predict_inputs; ins.f_inputs / ins.Q_inputs): what the batch changes
against one prediction per IMU sample, and what it must not change.

Stated tolerances (the INS of paper 000 at the ABPS recording's conditions, 100 Hz, alpha = 0.5):
over 0.1 s (10 samples) the batched prediction's mean is within 1e-5 standard deviations of the
per-sample one and its standard deviations within 1e-4 (relative); over 0.4 s (40 samples, one ABPS
cycle) within 1e-4 sd and 1e-3. The UKF and SR-UKF batched predictions agree to 1e-9.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import expm

from fusion import quaternion as quat
from fusion import testing
from fusion.registry import default_registry

DT = 0.01


def ins(**kw):
    return testing.build("process", "ins", {"integration": "trapezoidal", **kw})


def flt(name, **kw):
    cls = default_registry().get("filter", name)
    return cls(cls.Params(alpha=0.5, **kw))


def belief_and_inputs(k):
    proc = ins()
    x0 = proc.layout.vector({"p": [5.0, 1.0, -0.3], "v": [0.8, 0.2, 0.0], "q": quat.from_euler(0.02, -0.01, 0.3),
                             "ba": [0.01, -0.02, 0.01], "bw": [1e-3, -5e-4, 2e-3]})
    P0 = np.diag([0.03**2] * 6 + [0.005**2] * 4 + [0.01**2] * 3 + [2e-4**2] * 3)
    t = np.arange(k) * DT
    us = np.column_stack([0.3 * np.sin(t), 0.2 * np.cos(t), -9.8 + 0.05 * np.sin(3 * t),
                          0.01 + 0 * t, -0.02 + 0 * t, 0.4 + 0.1 * t])        # a turn at 0.4-0.45 rad/s
    return proc, x0, P0, us, np.full(k, DT)


@pytest.mark.parametrize("integration", ["trapezoidal", "euler"])
@pytest.mark.parametrize("k", [2, 7, 17, 40])
def test_f_inputs_equals_k_calls_of_f(integration, k):
    rng = np.random.default_rng(k)
    proc = ins(integration=integration)
    X = testing.random_states(proc.layout, 33, seed=k)
    us = np.column_stack([rng.normal(size=(k, 3)) * 0.5 + [0, 0, -9.8], rng.normal(size=(k, 3)) * 0.5])
    dts = DT + 0.002 * rng.random(k)                      # uneven intervals (jitter)
    Y = X
    for u, dt in zip(us, dts):
        Y = proc.f(Y, u, dt)
    np.testing.assert_allclose(proc.f_inputs(X, us, dts), Y, rtol=0, atol=1e-13)
    assert proc.f_inputs(X[0], us, dts).shape == (16,)


def test_f_inputs_with_eta_or_earth_rate_loops_f():
    for kw in ({"eta": 10.0}, {"earth_rate": True, "latitude_deg": -26.0}):
        proc = ins(**kw)
        X = testing.random_states(proc.layout, 5, seed=1)
        us = np.tile([0.1, 0.0, -9.8, 0.0, 0.1, 0.3], (6, 1))
        Y = X
        for u in us:
            Y = proc.f(Y, u, DT)
        np.testing.assert_array_equal(proc.f_inputs(X, us, np.full(6, DT)), Y)


def test_Q_inputs_is_the_van_loan_discretisation():
    """Q_inputs == G (int e^{Fs} Q_c e^{F^T s} ds) G^T computed by Van Loan's matrix exponential."""
    proc = ins(accel_noise_density=2e-3, gyro_noise_density=5.8e-4, accel_bias_rw=1e-4, gyro_bias_rw=1.2e-5)
    _, x0, _, us, dts = belief_and_inputs(40)
    x1 = proc.normalize(proc.f_inputs(x0, us, dts))
    T = dts.sum()
    fn = (x1[3:6] - x0[3:6]) / T - proc.g_n
    C = quat.to_matrix(x0[6:10] + x1[6:10])
    F = np.zeros((15, 15))
    F[0:3, 3:6] = np.eye(3)
    F[3:6, 6:9] = -np.array([[0, -fn[2], fn[1]], [fn[2], 0, -fn[0]], [-fn[1], fn[0], 0]])
    F[3:6, 9:12] = F[6:9, 12:15] = -C
    Qc = np.diag([0] * 3 + [4e-6] * 3 + [5.8e-4**2] * 3 + [1e-8] * 3 + [1.2e-5**2] * 3)
    E = expm(np.block([[-F, Qc], [np.zeros((15, 15)), F.T]]) * T)
    Qe = E[15:, 15:].T @ E[:15, 15:]
    q = x1[6:10]
    G = np.zeros((16, 15))
    G[0:6, 0:6] = G[10:16, 9:15] = np.eye(6)
    G[6:10, 6:9] = 0.5 * np.array([[-q[1], -q[2], -q[3]], [q[0], q[3], -q[2]], [-q[3], q[0], q[1]], [q[2], -q[1], q[0]]])
    Qi = proc.Q_inputs(x0, x1, us, dts)
    # Van Loan's expm is accurate to a few eps of ||F T||, the product integration rounds alike: measured 4e-4 of
    # this 1e-12 of the largest element (numpy 1.26 / scipy 1.14 and numpy 2.4 / scipy 1.17 alike)
    np.testing.assert_allclose(Qi, G @ Qe @ G.T, rtol=0, atol=1e-12 * np.abs(Qi).max())
    np.testing.assert_array_equal(Qi, Qi.T)
    # one sample: Q plus couplings of order dt^2 (0.2% of the largest element at 100 Hz)
    x1 = proc.normalize(proc.f(x0, us[0], DT))
    Q1, Q0 = proc.Q_inputs(x0, x1, us[:1], dts[:1]), proc.Q(x1, us[0], DT)
    assert np.abs(Q1 - Q0).max() < 5e-3 * np.abs(Q0).max()
    # anisotropic densities take the general path and still match Q's blocks for one sample
    pa = ins(accel_noise_density=(2e-3, 3e-3, 4e-3), gyro_noise_density=(5e-4, 6e-4, 7e-4))
    Qa1, Qa0 = pa.Q_inputs(x0, x1, us[:1], dts[:1]), pa.Q(x1, us[0], DT)
    assert np.abs(Qa1 - Qa0).max() < 5e-3 * np.abs(Qa0).max()


@pytest.mark.parametrize("name", ["ukf", "srukf"])
@pytest.mark.parametrize("k,tol_mean,tol_sd", [(10, 1e-5, 1e-4), (40, 1e-4, 1e-3)])
def test_batched_prediction_agrees_with_per_sample(name, k, tol_mean, tol_sd):
    proc, x0, P0, us, dts = belief_and_inputs(k)
    fb, fs = flt(name), flt(name, batch_inputs=False)
    b0 = fb.initial_belief(0.0, x0, P0)
    runs = []
    f_inputs = proc.f_inputs
    proc.f_inputs = lambda X, u, d: runs.append(len(u)) or f_inputs(X, u, d)   # the batched fast path
    bb = fb.predict_inputs(b0, proc, us, dts)
    assert runs == [k]                                   # one draw of sigma points for the whole run
    bs = fs.predict_inputs(b0, proc, us, dts)
    assert runs == [k]                                   # batch_inputs: false: sample by sample
    assert bb.t == pytest.approx(bs.t)
    sd_b, sd_s = bb.sd, bs.sd
    assert (np.abs(bb.x - bs.x) / sd_s).max() < tol_mean      # in standard deviations, element by element
    assert np.abs(sd_b / sd_s - 1.0).max() < tol_sd
    corr = lambda P, sd: P / np.outer(sd, sd)
    assert np.abs(corr(bb.cov, sd_b) - corr(bs.cov, sd_s)).max() < tol_sd


def test_ukf_and_srukf_batched_predictions_agree():
    proc, x0, P0, us, dts = belief_and_inputs(40)
    u, s = flt("ukf"), flt("srukf")
    bu = u.predict_inputs(u.initial_belief(0.0, x0, P0), proc, us, dts)
    bs = s.predict_inputs(s.initial_belief(0.0, x0, P0), proc, us, dts)
    assert bs.S is not None and bs.P is None
    np.testing.assert_allclose(bs.x, bu.x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(bs.cov, bu.cov, rtol=0, atol=1e-9 * np.abs(bu.cov).max())


def test_base_predict_inputs_is_a_loop_of_predict():
    """kf/ekf/iekf (and ukf with batch_inputs: false): the same numbers as sample-by-sample predicts."""
    proc, x0, P0, us, dts = belief_and_inputs(5)
    for name in ("ekf", "iekf"):
        f = flt_plain(name)
        b = b0 = f.initial_belief(0.0, x0, P0)
        for u, dt in zip(us, dts):
            b = f.predict(b, proc, u, dt)
        bb = f.predict_inputs(b0, proc, us, dts)
        np.testing.assert_array_equal(bb.x, b.x)
        np.testing.assert_array_equal(bb.cov, b.cov)


def flt_plain(name):
    cls = default_registry().get("filter", name)
    return cls(cls.Params())


class Plain:
    """The INS as a third-party model without the optional run capabilities (f_inputs, Q_inputs): f, Q
    and normalize only, counting the calls of f."""

    def __init__(self, inner):
        self.inner = inner
        self.layout, self.input_dim, self.linear = inner.layout, inner.input_dim, False
        self.calls = 0

    def f(self, x, u, dt):
        self.calls += 1
        return self.inner.f(x, u, dt)

    def Q(self, x, u, dt):
        return self.inner.Q(x, u, dt)

    def normalize(self, x):
        return self.inner.normalize(x)


class PlainWithRunNoise(Plain):
    """... with InputRunNoise (Q_inputs) but no f_inputs: batched, the points through k calls of f."""

    def Q_inputs(self, x0, x1, us, dts):
        return self.inner.Q_inputs(x0, x1, us, dts)


@pytest.mark.parametrize("name", ["ukf", "srukf"])
def test_generic_process_without_batched_methods(name):
    """A process without Q_inputs (InputRunNoise): predict_inputs is k calls of predict, the same
    numbers (one Q of the whole interval added at the end would leave out the early samples' noise
    carried through the later dynamics; tester4 #7)."""
    proc, x0, P0, us, dts = belief_and_inputs(8)
    plain = Plain(proc)
    f = flt(name)
    b0 = f.initial_belief(0.0, x0, P0)
    b = f.predict_inputs(b0, plain, us, dts)
    assert plain.calls == 8                                  # one call per sample on all points
    one = b0
    for u, dt in zip(us, dts):
        one = f.predict(one, plain, u, float(dt))
    np.testing.assert_array_equal(b.x, one.x)
    np.testing.assert_array_equal(b.cov, one.cov)


@pytest.mark.parametrize("name", ["ukf", "srukf"])
def test_generic_process_with_run_noise_only(name):
    """Q_inputs without f_inputs: one draw of sigma points carried through k calls of f: the batched
    prediction of the model with both, to rounding."""
    proc, x0, P0, us, dts = belief_and_inputs(8)
    plain = PlainWithRunNoise(proc)
    f = flt(name)
    b = f.predict_inputs(f.initial_belief(0.0, x0, P0), plain, us, dts)
    assert plain.calls == 8
    ref = flt(name).predict_inputs(f.initial_belief(0.0, x0, P0), proc, us, dts)
    np.testing.assert_allclose(b.x, ref.x, rtol=0, atol=1e-12)     # f_inputs == k calls of f
    np.testing.assert_allclose(b.cov, ref.cov, rtol=0, atol=1e-12 * np.abs(ref.cov).max())


@pytest.mark.parametrize("name", ["ukf", "srukf"])
def test_nonlinear_input_driven_model_without_run_noise(name):
    """tester4 #7: the unicycle of tests/smoothing (wheel odometry: non-linear, input-driven, no
    Q_inputs), 100 samples of (2 m/s, 0.2 rad/s) at 100 Hz in one predict_inputs (batch_inputs default):
    the covariance within 1% of the EKF's (it was 25% too small: sd py 0.183 m against 0.210 m)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "smoothing"))
    from smoothing_models import Unicycle

    proc = Unicycle(Unicycle.Params(q=0.02))
    x0, P0 = np.array([0.0, 0.0, 0.3]), np.diag([0.01, 0.01, 0.001])
    us, dts = np.tile([2.0, 0.2], (100, 1)), np.full(100, DT)
    f, ekf = flt_plain(name), flt_plain("ekf")
    assert f.params.batch_inputs
    b = f.predict_inputs(f.initial_belief(0.0, x0, P0), proc, us, dts)
    e = ekf.predict_inputs(ekf.initial_belief(0.0, x0, P0), proc, us, dts)
    assert np.abs(b.cov - e.cov).max() < 0.01 * np.abs(e.cov).max()
    assert np.abs(b.sd / e.sd - 1.0).max() < 0.01
