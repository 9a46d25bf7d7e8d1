"""The compiled covariance arithmetic of the Kalman filters (plugins/filters/_kalman_kernel.c) against its numpy
reference and an independent one, and its refusal of bad input.

* ``propagate`` (the EKF's chain over a run, ``P <- F_j P F_j^T + Q_j``) against ``ekf.propagate_run`` on the
  INS's own runs (10 and 22 states, 1-40 samples), a Gauss-Markov-extended run (23 states) and dense random
  F (3, 16 and 23 states), asymmetric P and Q included.
* ``update`` through ``linearised_update`` (the EKF's) against ``linearised_update_numpy`` and the textbook
  formulas with an explicit inverse: sparse H (the magnetometer's q columns, a GPS's p and v columns), dense
  H, plugin (untrusted) models, a gate that rejects, a non-positive-definite S (the numpy code's repair).
"""
from __future__ import annotations

from typing import ClassVar

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion import kernels
from fusion.api import Belief, BuildContext, MeasurementModel, Params, StateLayout
from fusion.config import build_component
from fusion.registry import default_registry
from fusion_plugins.filters import base
from fusion_plugins.filters.base import linearised_update, linearised_update_numpy
from fusion_plugins.filters.ekf import ExtendedKalmanFilter, propagate_run
from fusion_plugins.gates.chi2 import Chi2Gate
from fusion_plugins.process.ins_linearise import linearise_run_numpy

KERNEL = base.KERNEL
pytestmark = pytest.mark.skipif(KERNEL is None and kernels.missing_allowed(), reason="_kalman_kernel not built (python setup.py build_ext "
                                "--inplace) or FUSION_PURE_PYTHON set")


def _close(a: np.ndarray, b: np.ndarray, rtol: float = 1e-12) -> None:
    """Entry by entry to ``rtol``, or to 1e-14 of the array's largest entry (cancellations)."""
    np.testing.assert_allclose(a, b, rtol=rtol, atol=1e-14 * max(np.abs(b).max(), 1e-300))


def _spd(rng, n: int, scale: float = 1.0) -> np.ndarray:
    A = rng.normal(size=(n, n)) * scale
    return A @ A.T + 1e-3 * scale * scale * np.eye(n)


def _ins_run(rng, n: int, k: int):
    x = np.zeros(n)
    x[0:6] = rng.normal(0, 3, 6)
    x[6:10] = Rotation.random(random_state=rng).as_quat(scalar_first=True)
    if n == 22:
        x[16:22] = 1.0 + rng.normal(0, 0.03, 6)
    us = np.c_[rng.normal(0, 2, (k, 3)) + [0, 0, -9.8], rng.normal(0, 0.5, (k, 3))]
    dts = rng.uniform(0.01, 0.03, k)
    Qb = np.zeros((k, n, n))
    Qb[:, range(n), range(n)] = rng.uniform(1e-8, 1e-4, n)
    _, F, Q = linearise_run_numpy(x, us, dts, 9.80665, True, Qb, 7.6e-7, 1e-12)
    return F, Q


# ---------------------------------------------------------------------------- propagate
@pytest.mark.parametrize("n", [10, 22])
@pytest.mark.parametrize("k", [1, 2, 9, 40])
def test_propagate_is_the_numpy_chain_on_ins_runs(n, k):
    rng = np.random.default_rng(10 * n + k)
    for _ in range(3):
        F, Q = _ins_run(rng, n, k)
        P = _spd(rng, n, 0.1)
        out = np.empty((n, n))
        KERNEL.propagate(P, F, Q, out)
        _close(out, propagate_run(P, F, Q))
        np.testing.assert_array_equal(out, out.T)


@pytest.mark.parametrize("n", [3, 16, 23])
def test_propagate_is_the_numpy_chain_on_dense_and_asymmetric_input(n):
    """Dense F (no identity row), and P, Q not symmetric: the numpy loop's final symmetrisation is that of
    the kernel's symmetric parts (the map is linear)."""
    rng = np.random.default_rng(n)
    F = rng.normal(size=(5, n, n)) * 0.3
    F[2, 1] = 0.0                               # a zero row
    F[3, 0] = np.eye(n)[0]                      # an identity row
    Q = rng.normal(size=(5, n, n)) * 1e-3
    P = rng.normal(size=(n, n))
    out = np.empty((n, n))
    KERNEL.propagate(P, F, Q, out)
    _close(out, propagate_run(P, F, Q), rtol=1e-11)
    np.testing.assert_array_equal(out, out.T)


def test_propagate_of_no_sample_is_the_symmetric_part():
    rng = np.random.default_rng(1)
    P = rng.normal(size=(4, 4))
    out = np.empty((4, 4))
    KERNEL.propagate(P, np.empty((0, 4, 4)), np.empty((0, 4, 4)), out)
    np.testing.assert_array_equal(out, (P + P.T) * 0.5)


def test_ekf_predict_inputs_with_and_without_the_kernel(monkeypatch):
    """The EKF's run through a Gauss-Markov-extended INS (23 states): kernel and numpy chain agree."""
    ins = build_component(default_registry(), "process", {
        "type": "ins", "states": 22, "integration": "euler", "eta": 0.0, "earth_rate": False, "gravity": 9.80665,
        "accel_noise_density": 3.4e-3, "gyro_noise_density": 8.7e-4, "accel_bias_rw": 5e-3, "gyro_bias_rw": 5e-5,
        "accel_scale_rw": 1e-4, "gyro_scale_rw": 1e-4, "hold_after": 0.03,
        "gauss_markov": [{"name": "hz", "size": 1, "tau": 10.0, "sd": 0.1}]}, BuildContext())
    rng = np.random.default_rng(2)
    x = np.zeros(23)
    x[6:10] = Rotation.random(random_state=rng).as_quat(scalar_first=True)
    x[16:22] = 1.0
    b0 = Belief(0.0, x, P=_spd(rng, 23, 0.05))
    us = np.c_[rng.normal(0, 2, (7, 3)) + [0, 0, -9.8], rng.normal(0, 0.5, (7, 3))]
    dts = rng.uniform(0.015, 0.025, 7)
    ekf = ExtendedKalmanFilter()
    got = ekf.predict_inputs(b0, ins, us, dts)
    monkeypatch.setattr(base, "KERNEL", None)
    ref = ekf.predict_inputs(b0, ins, us, dts)
    np.testing.assert_array_equal(got.x, ref.x)
    _close(got.P, ref.P)
    assert got.t == ref.t


# ---------------------------------------------------------------------------- update
class Columns(MeasurementModel):
    """z = H x with H nonzero in some columns only (a plugin's model: untrusted, its outputs checked)."""

    name: ClassVar[str] = "columns_test"

    class Params(Params):
        pass

    def __init__(self, H: np.ndarray):
        super().__init__()
        self.H = H
        self.dim = H.shape[0]

    def h(self, x):
        return np.asarray(x) @ self.H.T

    def jacobian(self, x):
        return self.H.copy()


def _problem(rng, n: int, m: int, cols):
    H = np.zeros((m, n))
    H[:, cols] = rng.normal(size=(m, len(cols)))
    x = rng.normal(size=n)
    P = _spd(rng, n, 0.3)
    R = _spd(rng, m, 0.1)
    z = H @ x + rng.normal(size=m) * 0.3
    return Belief(1.0, x, P=P), Columns(H), z, R


def _textbook(belief, H, z, R):
    P, x = belief.P, belief.x
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    A = np.eye(len(x)) - K @ H
    y = z - H @ x
    return x + K @ y, A @ P @ A.T + K @ R @ K.T, S, float(y @ np.linalg.solve(S, y))


@pytest.mark.parametrize("n, m, cols", [(22, 3, [6, 7, 8, 9]), (22, 6, [0, 1, 2, 3, 4, 5]), (16, 3, range(16)),
                                        (10, 1, [9]), (23, 4, [0, 5, 22])])
def test_update_is_the_numpy_update_and_the_textbook(n, m, cols):
    rng = np.random.default_rng(n + m)
    ekf = ExtendedKalmanFilter()
    for _ in range(5):
        belief, model, z, R = _problem(rng, n, m, list(cols))
        got = linearised_update(ekf, belief, model, z, R, None)
        ref = linearised_update_numpy(ekf, belief, model, z, R, None)
        assert got.accepted and ref.accepted and got.events == ref.events == () and got.iterations == 1
        _close(got.belief.x, ref.belief.x)
        _close(got.belief.P, ref.belief.P, rtol=1e-11)
        np.testing.assert_array_equal(got.belief.P, got.belief.P.T)
        _close(got.S, ref.S)
        np.testing.assert_array_equal(got.innovation, ref.innovation)
        assert got.nis == pytest.approx(ref.nis, rel=1e-12)
        x1, P1, S, nis = _textbook(belief, model.H, z, R)
        _close(got.belief.x, x1, rtol=1e-10)
        _close(got.belief.P, P1, rtol=1e-9)
        assert got.nis == pytest.approx(nis, rel=1e-10)


def test_magnetometer_update_with_and_without_the_kernel(monkeypatch):
    """One of fusion's own (trusted) models, with the normalisation of the updated quaternion."""
    layout = StateLayout.parse("p:3 v:3 q:4:quaternion ba:3 bw:3 sa:3 sw:3")
    mag = build_component(default_registry(), "measurement", {
        "type": "magnetometer", "declination_deg": -20.5, "inclination_deg": -36.0, "intensity": 23.5},
        BuildContext(layout=layout))
    ekf = build_component(default_registry(), "filter", {"type": "ekf"}, BuildContext(layout=layout))
    rng = np.random.default_rng(8)
    x = np.zeros(22)
    x[6:10] = Rotation.random(random_state=rng).as_quat(scalar_first=True)
    x[16:22] = 1.0
    belief = Belief(0.0, x, P=_spd(rng, 22, 0.02))
    z = mag.h(x) + rng.normal(size=3) * 0.2
    R = np.eye(3) * 0.04
    got = ekf.update(belief, mag, z, R)
    monkeypatch.setattr(base, "KERNEL", None)
    ref = ekf.update(belief, mag, z, R)
    _close(got.belief.x, ref.belief.x)
    _close(got.belief.P, ref.belief.P, rtol=1e-11)
    assert np.linalg.norm(got.belief.x[6:10]) == pytest.approx(1.0, abs=1e-15)


def test_rejected_update_leaves_the_belief():
    rng = np.random.default_rng(9)
    belief, model, z, R = _problem(rng, 22, 3, [6, 7, 8, 9])
    z = z + 100.0
    gate = Chi2Gate(Chi2Gate.Params(probability=0.99))
    ekf = ExtendedKalmanFilter()
    got = linearised_update(ekf, belief, model, z, R, gate)
    ref = linearised_update_numpy(ekf, belief, model, z, R, gate)
    assert not got.accepted and not ref.accepted
    assert got.belief is belief
    assert got.nis == pytest.approx(ref.nis, rel=1e-12)


def test_not_positive_definite_innovation_takes_the_numpy_repair():
    """S not positive definite (a negative R): the kernel declines and the numpy code repairs S, reporting it."""
    rng = np.random.default_rng(10)
    belief, model, z, R = _problem(rng, 6, 2, [0, 1])
    R = -10.0 * np.eye(2) - model.H @ belief.P @ model.H.T
    ekf = ExtendedKalmanFilter()
    assert KERNEL.update(belief.x, belief.P, model.H, R, z - model.h(belief.x), np.empty((2, 2)), np.empty(6),
                         np.empty((6, 6))) is None
    got = linearised_update(ekf, belief, model, z, R, None)
    ref = linearised_update_numpy(ekf, belief, model, z, R, None)
    assert [e.kind for e in got.events] == ["not_positive_definite"]
    np.testing.assert_array_equal(got.belief.x, ref.belief.x)
    np.testing.assert_array_equal(got.belief.P, ref.belief.P)


def test_update_of_a_nan_innovation_covariance_declines():
    P = np.eye(3)
    H = np.array([[np.nan, 0.0, 0.0]])
    assert KERNEL.update(np.zeros(3), P, H, np.eye(1), np.zeros(1), np.empty((1, 1)), np.empty(3),
                         np.empty((3, 3))) is None


# ---------------------------------------------------------------------------- bad input
def _update_args(n=5, m=2):
    return dict(x=np.zeros(n), P=np.eye(n), H=np.ones((m, n)), R=np.eye(m), r=np.zeros(m), S=np.empty((m, m)),
                x1=np.empty(n), P1=np.empty((n, n)))


@pytest.mark.parametrize("field, bad, error, words", [
    ("x", np.zeros((5, 1)), ValueError, "x must have 1 dimension"),
    ("P", np.eye(4), ValueError, "P has length 4 along axis 0, expected 5"),
    ("P", np.eye(5, dtype=np.float32), TypeError, "P must be a float64 array"),
    ("H", np.ones((2, 4)), ValueError, "H has length 4 along axis 1, expected 5"),
    ("H", np.ones((5, 2)).T, ValueError, "H must be C-contiguous"),
    ("R", np.eye(3), ValueError, "R has length 3 along axis 0, expected 2"),
    ("r", [0.0, 0.0], TypeError, "r must be a float64 array (buffer protocol), got list"),
    ("S", np.empty((2, 3)), ValueError, "S has length 3"),
    ("x1", np.empty(4), ValueError, "x1 has length 4"),
    ("P1", np.empty((5, 5), np.int64), TypeError, "P1 must be a float64 array"),
])
def test_update_refuses_bad_input(field, bad, error, words):
    a = _update_args()
    a[field] = bad
    with pytest.raises(error) as e:
        KERNEL.update(*a.values())
    assert words in str(e.value)


def test_outputs_must_be_writable():
    a = _update_args()
    a["P1"].flags.writeable = False
    with pytest.raises(ValueError, match="P1 is read-only"):
        KERNEL.update(*a.values())
    out = np.empty((3, 3))
    out.flags.writeable = False
    with pytest.raises(ValueError, match="out is read-only"):
        KERNEL.propagate(np.eye(3), np.zeros((1, 3, 3)), np.zeros((1, 3, 3)), out)


@pytest.mark.parametrize("args, error, words", [
    ((np.ones((3, 4)), np.zeros((1, 3, 3)), np.zeros((1, 3, 3)), np.empty((3, 3))), ValueError, "P must be square"),
    ((np.eye(3), np.zeros((1, 3, 4)), np.zeros((1, 3, 3)), np.empty((3, 3))), ValueError, "F has length 4"),
    ((np.eye(3), np.zeros((2, 3, 3)), np.zeros((1, 3, 3)), np.empty((3, 3))), ValueError, "Q has length 1"),
    ((np.eye(3), np.zeros((1, 3, 3)), np.zeros((1, 3, 3)), np.empty((3, 2))), ValueError, "out has length 2"),
    ((np.eye(3), np.zeros((1, 3, 3), np.float32), np.zeros((1, 3, 3)), np.empty((3, 3))), TypeError, "F must be"),
    ((np.eye(3), np.zeros((1, 3, 3)), np.zeros((1, 3, 3))), TypeError, "4 arguments"),
])
def test_propagate_refuses_bad_input(args, error, words):
    with pytest.raises(error) as e:
        KERNEL.propagate(*args)
    assert words in str(e.value)
