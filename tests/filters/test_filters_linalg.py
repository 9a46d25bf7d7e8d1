"""Building blocks: vectorised rank-1 cholupdate, QR square roots, recovery of a lost positive
definiteness, numerical Jacobians; and the filters' recovery from a failed downdate without NaN."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from fusion import testing
from fusion.api import MeasurementModel, ProcessModel, StateLayout
from fusion_plugins.filters.jacobian import numerical_jacobian
from fusion_plugins.filters.linalg import (cholupdate, psd_sqrt_rows, qr_lower, recover_factor,
                                           robust_cholesky, solve_lower)


def _spd(rng, n, cond=10.0):
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return (Q * np.geomspace(1.0, cond, n)) @ Q.T


@settings(max_examples=200, deadline=None)
@given(n=st.integers(1, 16), seed=st.integers(0, 2 ** 32 - 1), w=st.floats(-0.999, 50.0))
def test_cholupdate_matches_refactorisation(n, seed, w):
    rng = np.random.default_rng(seed)
    P = _spd(rng, n)
    L = np.linalg.cholesky(P)
    # scale v so that a downdate keeps P1 positive definite: w |L^-1 v|^2 > -1
    v = rng.standard_normal(n)
    v /= np.linalg.norm(np.linalg.solve(L, v))
    L1, ok = cholupdate(L, v, w)
    assert ok
    P1 = P + w * np.outer(v, v)
    assert np.array_equal(L1, np.tril(L1)) and (np.diagonal(L1) > 0).all()
    np.testing.assert_allclose(L1 @ L1.T, P1, atol=1e-10 * np.abs(P1).max() / (1.0 + w))
    np.testing.assert_allclose(L1, np.linalg.cholesky(P1), atol=1e-8 / (1.0 + w))


@pytest.mark.parametrize("n", [1, 4, 16])
def test_failed_downdate_is_detected(n):
    rng = np.random.default_rng(n)
    L = np.linalg.cholesky(_spd(rng, n))
    v = rng.standard_normal(n)
    v /= np.linalg.norm(np.linalg.solve(L, v))
    assert cholupdate(L, 1.5 * v, -1.0)[1] is False      # removes more than there is
    assert cholupdate(L, 1.001 * v, -1.0)[1] is False
    assert cholupdate(L, np.full(n, np.nan), 1.0)[1] is False
    assert cholupdate(L, 0.5 * v, -1.0)[1] is True


def test_qr_lower_and_psd_sqrt():
    rng = np.random.default_rng(0)
    A = rng.standard_normal((13, 5))
    L = qr_lower(A)
    assert np.array_equal(L, np.tril(L)) and (np.diagonal(L) >= 0).all()
    np.testing.assert_allclose(L, np.linalg.cholesky(A.T @ A), atol=1e-12)
    Q = np.diag([1.0, 0.0, 2.0])                          # singular: Cholesky fails, eigen route
    B = psd_sqrt_rows(Q)
    np.testing.assert_allclose(B.T @ B, Q, atol=1e-15)
    L = np.tril(rng.standard_normal((4, 4))) + 3 * np.eye(4)
    Bm = rng.standard_normal((4, 3))
    np.testing.assert_allclose(L @ solve_lower(L, Bm), Bm, atol=1e-12)
    np.testing.assert_allclose(L.T @ solve_lower(L, Bm, trans=1), Bm, atol=1e-12)
    np.testing.assert_allclose(L @ solve_lower(L, Bm[:, 0]), Bm[:, 0], atol=1e-12)


def test_recover_factor():
    P = np.array([[1.0, 2.0], [2.0, 1.0]])                 # eigenvalues 3, -1
    L, recovered = robust_cholesky(P)
    assert recovered and np.isfinite(L).all()
    np.testing.assert_allclose(L @ L.T, [[1.5, 1.5], [1.5, 1.5]], atol=1e-9)
    with pytest.raises(FloatingPointError):
        recover_factor(np.array([[np.nan, 0.0], [0.0, 1.0]]))


def test_numerical_jacobian_matches_analytic():
    meas = testing.RangeMeasurement(testing.RangeMeasurement.Params(
        beacons=[[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0]]))
    x = np.array([5.0, 4.0, 1.0, 0.5])
    np.testing.assert_allclose(numerical_jacobian(meas.h, x), meas.jacobian(x), atol=1e-9)
    calls = []
    numerical_jacobian(lambda X: calls.append(X.shape) or meas.h(X), x)
    assert calls == [(8, 4)]                               # one vectorised call


# ---------------------------------------------------------------------------- recovery in the filters
class Square(ProcessModel):
    """x' = x^2 (1-D): with beta < 0 the unscented covariance of this step is negative."""

    name = "test_square"
    layout = StateLayout.parse("x:1")

    def f(self, x, u, dt):
        return np.asarray(x) ** 2

    def Q(self, x, u, dt):
        return np.array([[1e-12]])


class Identity1(MeasurementModel):
    name = "test_identity1"
    dim = 1

    def h(self, x):
        return np.asarray(x)[..., :1].copy()


@pytest.mark.parametrize("name,params", [
    ("srukf", {}), ("srukf", {"zeroth_point": "cholupdate"}), ("ukf", {}),
])
def test_loss_of_positive_definiteness_is_recovered_without_nan(name, params):
    """alpha=1, beta=-1 at x=0, P=1: sigma points 0, +-1 -> Y = 0, 1, 1, mean 1, and the unscented
    covariance is W_c^0 (Y_0 - mean)^2 = beta = -1 < 0: the downdate (srukf) or the next Cholesky
    (ukf) fails, is counted and repaired."""
    flt = testing.build("filter", name, {"alpha": 1.0, "beta": -1.0, "kappa": 0.0, **params})
    b = flt.initial_belief(0.0, np.array([0.0]), np.array([[1.0]]))
    b = flt.predict(b, Square(), None, 1.0)
    res = flt.update(b, Identity1(), np.array([0.9]), np.array([[0.1]]))
    # the repair comes back as a value: on the predicted belief and/or on the update's result
    ev = [e for e in b.events + res.events if e.kind == "not_positive_definite"]
    assert ev and ev[0].t in (0.0, 1.0) and "repaired" in ev[0].detail
    assert not hasattr(flt, "counters") and not hasattr(flt, "events")   # the filter kept nothing
    for arr in (res.belief.x, res.belief.cov, res.S, res.innovation):
        assert np.isfinite(arr).all()
    assert np.linalg.eigvalsh(res.belief.cov).min() >= 0.0
