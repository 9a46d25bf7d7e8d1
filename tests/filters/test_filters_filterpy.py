"""Our UKF == FilterPy's UnscentedKalmanFilter (MerweScaledSigmaPoints) on the range model, and our
KF == FilterPy's KalmanFilter (FilterPy is a test-only dependency)."""
from __future__ import annotations

import numpy as np
import pytest

from fusion import testing

import filterpy.kalman as filterpy_kalman  # the test extra: a missing one is a failure, not a skip

BEACONS = [[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0]]


def _sequence(steps, seed, proc, meas, sd):
    rng = np.random.default_rng(seed)
    x = np.array([5.0, 4.0, 1.0, 0.5])
    zs = []
    for _ in range(steps):
        x = proc.f(x, None, 0.1) + rng.multivariate_normal(np.zeros(4), proc.Q(x, None, 0.1))
        zs.append(meas.h(x) + rng.normal(0.0, sd, meas.dim))
    return zs


@pytest.mark.parametrize("alpha,beta,kappa", [(0.5, 2.0, 0.0), (1.0, 2.0, 1.0), (0.3, 2.0, -1.0)])
@pytest.mark.parametrize("linear_prediction", ["never", "auto"])
def test_ukf_equals_filterpy_ukf(alpha, beta, kappa, linear_prediction):
    proc = testing.ConstantVelocity()
    meas = testing.RangeMeasurement(testing.RangeMeasurement.Params(beacons=BEACONS))
    R = np.eye(4) * 0.1 ** 2
    zs = _sequence(200, 11, proc, meas, 0.1)
    x0, P0 = np.array([5.5, 3.5, 0.0, 0.0]), np.diag([1.0, 1.0, 0.5, 0.5])

    pts = filterpy_kalman.MerweScaledSigmaPoints(4, alpha=alpha, beta=beta, kappa=kappa)
    ref = filterpy_kalman.UnscentedKalmanFilter(4, 4, 0.1, meas.h, lambda x, dt: proc.f(x, None, dt), pts)
    ref.x, ref.P, ref.Q, ref.R = x0.copy(), P0.copy(), proc.Q(x0, None, 0.1), R

    ukf = testing.build("filter", "ukf", {"alpha": alpha, "beta": beta, "kappa": kappa,
                                          "linear_prediction": linear_prediction})
    b = ukf.initial_belief(0.0, x0, P0)
    worst = 0.0
    for z in zs:
        ref.predict()
        b = ukf.predict(b, proc, None, 0.1)
        worst = max(worst, np.abs(b.x - ref.x).max(), np.abs(b.P - ref.P).max())
        ref.update(z)
        res = ukf.update(b, meas, z, R)
        b = res.belief
        worst = max(worst, np.abs(b.x - ref.x).max(), np.abs(b.P - ref.P).max(),
                    np.abs(res.S - ref.S).max(), np.abs(res.innovation - ref.y).max())
        # closed-form equations both (no iteration, no stopping rule): the two differ only by rounding in another
        # order of operations (FilterPy inverts S, we solve), ~1e-12 of metre-sized states over 200 steps;
        # measured under 1 % of these tolerances with numpy 1.26 and 2.4, FilterPy 2.0.
        assert res.nis == pytest.approx(float(ref.y @ np.linalg.solve(ref.S, ref.y)), rel=1e-9)
    assert worst < 1e-9


def test_kf_equals_filterpy_kalman_filter():
    proc = testing.ConstantVelocity(testing.ConstantVelocity.Params(q=0.8))
    meas = testing.PositionMeasurement()
    R = np.diag([0.04, 0.09])
    zs = _sequence(300, 12, proc, meas, [0.2, 0.3])
    x0, P0 = np.array([5.0, 4.0, 0.0, 0.0]), np.diag([2.0, 2.0, 1.0, 1.0])

    ref = filterpy_kalman.KalmanFilter(4, 2)
    ref.x, ref.P, ref.F, ref.Q, ref.H, ref.R = x0.copy(), P0.copy(), proc.F(0.1), proc.Q(x0, None, 0.1), meas.H, R
    kf = testing.build("filter", "kf")
    b = kf.initial_belief(0.0, x0, P0)
    for z in zs:
        ref.predict()
        b = kf.predict(b, proc, None, 0.1)
        # the same linear equations in another order: rounding only, cond(S) * eps ~ 1e-15 relative here (S is
        # R plus a P of order 1); the tolerances leave 100x room over the largest difference measured
        np.testing.assert_allclose(b.x, ref.x, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(b.P, ref.P, rtol=1e-11, atol=1e-12)
        ref.update(z)
        res = kf.update(b, meas, z, R)
        b = res.belief
        np.testing.assert_allclose(b.x, ref.x, rtol=1e-11, atol=1e-11)
        np.testing.assert_allclose(b.P, ref.P, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(res.innovation, ref.y, atol=1e-12)
        np.testing.assert_allclose(res.S, ref.S, rtol=1e-11)
