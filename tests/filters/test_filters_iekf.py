"""The IEKF reaches the maximum a posteriori point of a strongly non-linear range problem, where the
EKF stops short; with one iteration it is the EKF."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from fusion import testing
from fusion.api import Belief

BEACONS = [[0.0, 0.0], [3.0, 0.0], [0.0, 3.0]]


def _problem():
    meas = testing.RangeMeasurement(testing.RangeMeasurement.Params(beacons=BEACONS, n=2))
    truth = np.array([1.0, 0.8])
    x_prior = np.array([2.2, 2.0])           # far from the truth on the scale of the beacon distances
    P = np.diag([1.0, 1.0])
    R = np.eye(3) * 0.05 ** 2
    z = meas.h(truth) + np.array([0.03, -0.02, 0.01])
    return meas, Belief(0.0, x_prior, P=P), R, z


def _cost_and_grad(x, meas, prior, R, z):
    dx = x - prior.x
    Pi = np.linalg.inv(prior.P)
    Ri = np.linalg.inv(R)
    r = z - meas.h(x)
    H = meas.jacobian(x)
    return float(dx @ Pi @ dx + r @ Ri @ r), 2 * (Pi @ dx - H.T @ Ri @ r)


def test_iekf_reaches_map_where_ekf_stops_short():
    meas, prior, R, z = _problem()
    ref = minimize(lambda x: _cost_and_grad(x, meas, prior, R, z), prior.x, jac=True, method="BFGS",
                   options={"gtol": 1e-9})
    assert np.linalg.norm(ref.jac) < 1e-5
    iekf = testing.build("filter", "iekf", {"max_iterations": 50, "tolerance": 1e-12})
    ekf = testing.build("filter", "ekf")
    ri = iekf.update(prior, meas, z, R)
    xi = ri.belief.x
    xe = ekf.update(prior, meas, z, R).belief.x
    ci, gi = _cost_and_grad(xi, meas, prior, R, z)
    ce, ge = _cost_and_grad(xe, meas, prior, R, z)
    c0, g0 = _cost_and_grad(prior.x, meas, prior, R, z)
    assert np.linalg.norm(gi) < 1e-6 * np.linalg.norm(g0)          # a stationary point
    # The one BFGS finds, as far as its stopping rule places it: |x - x*| <= |grad| / lambda_min(Hessian), with
    # the Gauss-Newton Hessian 2 (P^-1 + H^T R^-1 H) at the solution (a residual this small changes it little).
    H = meas.jacobian(xi)
    hess = 2 * (np.linalg.inv(prior.P) + H.T @ np.linalg.inv(R) @ H)
    reach = np.linalg.norm(ref.jac) / np.linalg.eigvalsh(hess).min()
    assert np.linalg.norm(xi - ref.x) <= 2 * reach + 1e-12
    assert ci <= ref.fun * (1 + 1e-12)                               # no worse than the reference's point
    assert np.linalg.norm(ge) > 1e-2 * np.linalg.norm(g0)           # the EKF stops short
    assert ce > 10 * ci
    assert 2 < ri.iterations < 50


def test_iekf_one_iteration_is_ekf_and_tolerance_stops_early():
    meas, prior, R, z = _problem()
    ekf = testing.build("filter", "ekf")
    one = testing.build("filter", "iekf", {"max_iterations": 1})
    a, b = ekf.update(prior, meas, z, R), one.update(prior, meas, z, R)
    assert np.array_equal(a.belief.x, b.belief.x) and np.array_equal(a.belief.P, b.belief.P)
    loose = testing.build("filter", "iekf", {"max_iterations": 50, "tolerance": 1e-2})
    tight = testing.build("filter", "iekf", {"max_iterations": 50, "tolerance": 1e-12})
    assert a.iterations == b.iterations == 1
    assert loose.update(prior, meas, z, R).iterations < tight.update(prior, meas, z, R).iterations


def test_iekf_reports_prior_innovation():
    """Innovation, S, NIS (and so the gate decision) are the prior's, as in the EKF (to rounding: the EKF's
    one-iteration update may run in C, _kalman_kernel.c, the iterated one is numpy's)."""
    meas, prior, R, z = _problem()
    a = testing.build("filter", "ekf").update(prior, meas, z, R)
    b = testing.build("filter", "iekf").update(prior, meas, z, R)
    assert np.array_equal(a.innovation, b.innovation) and a.nis == pytest.approx(b.nis, rel=1e-13, abs=0)
