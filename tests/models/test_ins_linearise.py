"""The EKF's run of IMU samples (capability LinearisesInputRuns, plugins/process/ins_linearise.py): the
vectorised means, Jacobians and noise of a run equal the per-sample fast path (``f``, ``jacobian``, ``Q``,
one sample at a time), and ``ekf.predict_inputs`` through them equals k calls of ``ekf.predict``."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion.api import BuildContext, LinearisesInputRuns, has
from fusion.config import build_component
from fusion.registry import default_registry
from fusion_plugins.filters.ekf import ExtendedKalmanFilter
from fusion_plugins.filters.jacobian import numerical_jacobian

G = 9.80665


def random_state(rng, states):
    x = np.zeros(states)
    x[0:6] = rng.normal(0, 3, 6)
    x[6:10] = Rotation.random(random_state=rng).as_quat(scalar_first=True)
    if states == 22:
        x[10:13] = rng.normal(0, 0.1, 3)
        x[13:16] = rng.normal(0, 0.01, 3)
        x[16:22] = 1.0 + rng.normal(0, 0.03, 6)
    return x


def imu(rng):
    return np.r_[rng.normal(0, 2, 3) + [0, 0, -G], rng.normal(0, 0.5, 3)]

PAPER_002 = dict(integration="euler", eta=0.0, earth_rate=False, gravity=9.80665, accel_noise_density=3.4e-3,
                 gyro_noise_density=8.7e-4, accel_bias_rw=5e-3, gyro_bias_rw=5e-5, hold_after=0.03)


def make(states, **kw):
    extra = {"accel_scale_rw": 1e-4, "gyro_scale_rw": 1e-4} if states == 22 else {}
    return build_component(default_registry(), "process",
                           {"type": "ins", "states": states, **PAPER_002, **extra, **kw}, BuildContext())


def run_inputs(rng, k, rate_scale=1.0):
    us = np.array([imu(rng) for _ in range(k)])
    us[:, 3:] *= rate_scale
    return us


@pytest.mark.parametrize("states", [10, 22])
@pytest.mark.parametrize("rate_scale", [1.0, 1e-3, 0.0])   # ordinary turns, |h| < 1e-4 (series), no rotation
def test_run_equals_the_per_sample_fast_path(states, rate_scale):
    rng = np.random.default_rng(7 + states)
    m = make(states)
    assert has(m, LinearisesInputRuns)
    for _ in range(10):
        x = random_state(rng, states)
        k = int(rng.integers(1, 12))
        us = run_inputs(rng, k, rate_scale)
        dts = rng.uniform(0.015, 0.025, k)
        x_end, F, Q = m.linearise_inputs(x, us, dts)
        assert F.shape == Q.shape == (k, states, states)
        xj = x
        for j in range(k):
            np.testing.assert_allclose(F[j], m.jacobian(xj, us[j], float(dts[j])), rtol=0, atol=1e-13)
            np.testing.assert_allclose(Q[j], m.Q(xj, us[j], float(dts[j])), rtol=1e-12, atol=1e-22)
            xj = m.normalize(m.f(xj, us[j], float(dts[j])))
        np.testing.assert_allclose(x_end, xj, rtol=0, atol=1e-13)


def test_run_jacobians_match_central_differences():
    """An independent reference: F of each sample against numerical differences of one f step."""
    rng = np.random.default_rng(3)
    m = make(22)
    x = random_state(rng, 22)
    us = run_inputs(rng, 4)
    dts = np.full(4, 0.02)
    _, F, _ = m.linearise_inputs(x, us, dts)
    xj = x
    for j in range(4):
        Fn = numerical_jacobian(lambda X: m.f(X, us[j], 0.02), xj)
        np.testing.assert_allclose(F[j], Fn, atol=1e-7)
        xj = m.normalize(m.f(xj, us[j], 0.02))


def test_without_the_fast_path_there_is_no_run_linearisation():
    rng = np.random.default_rng(4)
    x = random_state(rng, 22)
    us = run_inputs(rng, 3)
    assert make(22, integration="trapezoidal").linearise_inputs(x, us, np.full(3, 0.02)) is None
    m = make(22)
    assert m.linearise_inputs(x, us, np.array([0.02, 0.5, 0.02])) is None      # a gap beyond hold_after
    assert m.linearise_inputs(x, us, np.array([0.02, 0.0, 0.02])) is None      # a zero step


@pytest.mark.parametrize("states", [10, 22])
def test_ekf_predict_inputs_equals_k_predicts(states):
    rng = np.random.default_rng(11)
    m = make(states)
    ekf = ExtendedKalmanFilter()
    for _ in range(5):
        x = random_state(rng, states)
        A = rng.normal(size=(states, states)) * 0.05
        b0 = ekf.initial_belief(2.0, x, A @ A.T + 1e-4 * np.eye(states))
        k = int(rng.integers(2, 15))
        us = run_inputs(rng, k)
        dts = np.full(k, 0.02)
        batched = ekf.predict_inputs(b0, m, us, dts)
        b = b0
        for u, dt in zip(us, dts):
            b = ekf.predict(b, m, u, float(dt))
        assert batched.t == pytest.approx(b.t, abs=1e-12)
        np.testing.assert_allclose(batched.x, b.x, rtol=0, atol=1e-12)
        np.testing.assert_allclose(batched.P, b.P, rtol=1e-11, atol=1e-16)
        np.testing.assert_array_equal(batched.P, batched.P.T)


def test_ekf_falls_back_to_per_sample_predictions():
    """A run the model cannot linearise in one call (a gap beyond hold_after) gives k predictions."""
    rng = np.random.default_rng(12)
    m = make(22)
    ekf = ExtendedKalmanFilter()
    x = random_state(rng, 22)
    b0 = ekf.initial_belief(0.0, x, 1e-3 * np.eye(22))
    us = run_inputs(rng, 3)
    dts = np.array([0.02, 0.2, 0.02])
    batched = ekf.predict_inputs(b0, m, us, dts)
    b = b0
    for u, dt in zip(us, dts):
        b = ekf.predict(b, m, u, float(dt))
    np.testing.assert_array_equal(batched.x, b.x)
    np.testing.assert_array_equal(batched.P, b.P)


def test_gauss_markov_blocks_keep_the_run_path():
    """22 states with a Gauss-Markov block appended (ins gauss_markov): the run of samples is the INS's with
    the block's exact decay and noise, and ekf.predict_inputs still equals k predicts."""
    rng = np.random.default_rng(21)
    m = make(22, gauss_markov=[{"name": "hz", "size": 1, "tau": 10.0, "sd": 0.1}])
    assert m.layout.n == 23 and has(m, LinearisesInputRuns)
    assert make(16, gauss_markov=[{"name": "hz", "size": 1, "tau": 10.0, "sd": 0.1}]).linearise_inputs(
        np.r_[np.zeros(6), 1.0, np.zeros(10)], run_inputs(rng, 2), np.full(2, 0.02)) is None   # 16: no run path
    ekf = ExtendedKalmanFilter()
    x = np.r_[random_state(rng, 22), 0.05]
    b0 = ekf.initial_belief(0.0, x, 1e-3 * np.eye(23))
    us, dts = run_inputs(rng, 6), rng.uniform(0.015, 0.025, 6)
    x_end, F, Q = m.linearise_inputs(x, us, dts)
    np.testing.assert_allclose(F[:, 22, 22], np.exp(-dts / 10.0), rtol=1e-15)
    np.testing.assert_allclose(Q[:, 22, 22], 0.01 * (1 - np.exp(-2 * dts / 10.0)), rtol=1e-12)
    assert x_end[22] == pytest.approx(0.05 * np.exp(-dts.sum() / 10.0), rel=1e-14)
    b = b0
    for u, dt in zip(us, dts):
        b = ekf.predict(b, m, u, float(dt))
    batched = ekf.predict_inputs(b0, m, us, dts)
    np.testing.assert_allclose(batched.x, b.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(batched.P, b.P, rtol=1e-11, atol=1e-16)
