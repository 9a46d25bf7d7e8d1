"""Solver ``triad`` (paper 002 eq. 7, Improved TRIAD) against scipy's Rotation.align_vectors, the propagated
covariance against Monte Carlo, and the ``attitude`` measurement it feeds."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion import quaternion as quat
from fusion.api import BuildContext, Message, StateLayout
from fusion_plugins.filters.jacobian import numerical_jacobian
from fusion_plugins.measurement.attitude import Attitude, AttitudeParams, covariance_in_state, error_to_quaternion
from fusion_plugins.solvers.triad import (TriadParams, TriadSolver, attitude_covariance, improved_triad, solve,
                                          triad)

G_N = np.array([0.0, 0.0, 9.80665])
M_N = np.array([17.81, -6.66, -13.81])        # uT, the scenario's field (southern hemisphere, pointing up)
L16 = StateLayout.parse("p:3 v:3 q:4:quaternion ba:3 bw:3")


def body(C):
    return C.T @ G_N, C.T @ M_N


def test_exact_vectors_give_the_rotation_both_ways():
    for r in Rotation.random(20, random_state=0):
        C = r.as_matrix()
        b1, b2 = body(C)
        np.testing.assert_allclose(triad(b1, b2, G_N, M_N), C, atol=1e-14)
        np.testing.assert_allclose(improved_triad(b1, b2, G_N, M_N, 0.01, 0.03), C, atol=1e-14)


def test_triad_is_align_vectors_with_the_first_vector_exact():
    """TRIAD matches vector 1 exactly and vector 2 as well as it can: Wahba's problem with an infinite
    weight on vector 1, which scipy solves in closed form."""
    rng = np.random.default_rng(1)
    for r in Rotation.random(30, random_state=2):
        b1, b2 = body(r.as_matrix())
        b1, b2 = b1 + rng.normal(0, 0.3, 3), b2 + rng.normal(0, 3.0, 3)
        ref, _ = Rotation.align_vectors(np.array([G_N, M_N]), np.array([b1, b2]), weights=[np.inf, 1.0])
        # both closed form (align_vectors' infinite weight is an exact construction, no iteration): rounding
        # only, measured 2e-7 of this 1e-12 on unit-norm matrix elements
        np.testing.assert_allclose(triad(b1, b2, G_N, M_N), ref.as_matrix(), atol=1e-12)


def test_vectorised_over_leading_axes():
    rs = Rotation.random(7, random_state=3)
    B1 = np.einsum("kji,j->ki", rs.as_matrix(), G_N)
    B2 = np.einsum("kji,j->ki", rs.as_matrix(), M_N)
    np.testing.assert_allclose(triad(B1, B2, G_N, M_N), rs.as_matrix(), atol=1e-14)
    np.testing.assert_allclose(improved_triad(B1, B2, G_N, M_N), rs.as_matrix(), atol=1e-14)


def _angle(Ca, Cb):
    return Rotation.from_matrix(Ca @ np.swapaxes(Cb, -1, -2)).magnitude()


def test_improved_triad_is_nearer_the_optimal_solution_than_triad():
    """With comparable angular accuracies, the weighted two-anchor TRIAD is much closer to the optimal
    (weighted Wahba, scipy align_vectors) attitude and to the truth than TRIAD anchored on gravity."""
    rng = np.random.default_rng(4)
    sig1, sig2 = 0.02, 0.02                                  # rad, angular sd of each direction
    e_t, e_i, d_t, d_i = [], [], [], []
    for r in Rotation.random(400, random_state=5):
        C = r.as_matrix()
        b1, b2 = body(C)
        b1 = b1 + rng.normal(0, sig1 * 9.80665, 3)
        b2 = b2 + rng.normal(0, sig2 * np.linalg.norm(M_N), 3)
        opt, _ = Rotation.align_vectors(np.array([G_N / 9.80665, M_N / np.linalg.norm(M_N)]),
                                        np.array([b1 / np.linalg.norm(b1), b2 / np.linalg.norm(b2)]),
                                        weights=[1 / sig1**2, 1 / sig2**2])
        At, Ai = triad(b1, b2, G_N, M_N), improved_triad(b1, b2, G_N, M_N, sig1, sig2)
        d_t.append(_angle(At, opt.as_matrix()))
        d_i.append(_angle(Ai, opt.as_matrix()))
        e_t.append(_angle(At, C))
        e_i.append(_angle(Ai, C))
    assert np.mean(d_i) < 0.5 * np.mean(d_t)
    assert np.mean(np.square(e_i)) < np.mean(np.square(e_t))


@pytest.mark.parametrize("method", ["triad", "improved_triad"])
def test_propagated_covariance_matches_monte_carlo(method):
    rng = np.random.default_rng(6)
    C = Rotation.from_euler("ZYX", [0.7, 0.1, -0.2]).as_matrix()
    b1, b2 = body(C)
    sa, sm = 0.05, 0.3
    P, J1 = attitude_covariance(method, b1, b2, G_N, M_N, np.eye(3) * sa**2, np.eye(3) * sm**2)
    N = 20000
    B1, B2 = b1 + rng.normal(0, sa, (N, 3)), b2 + rng.normal(0, sm, (N, 3))
    Cs = solve(method, B1, B2, G_N, M_N, sa / 9.80665, sm / np.linalg.norm(M_N))
    d = Rotation.from_matrix(Cs @ C.T).as_rotvec()           # C_est = exp(d) C_true
    S = np.cov(d.T)
    # sample covariance of N draws: each element within ~4 standard errors
    se = np.sqrt((S**2 + np.outer(np.diag(S), np.diag(S))) / N)
    assert np.all(np.abs(S - P) < 4 * se + 1e-12)
    # J1 is the sensitivity to the accelerometer vector (numerical check of the linearisation)
    fun = lambda X: Rotation.from_matrix(solve(method, X, np.broadcast_to(b2, X.shape), G_N, M_N,
                                                sa / 9.80665, sm / np.linalg.norm(M_N)) @ C.T).as_rotvec()
    np.testing.assert_allclose(J1, numerical_jacobian(fun, b1), atol=1e-6)


def test_solver_emits_fix_with_covariance_from_the_held_accelerometer():
    s = TriadSolver(TriadParams(field_ned=tuple(M_N), accel_sd=0.05, accel_disturbance_sd=0.0, mag_sd=0.3),
                    BuildContext(layout=L16))
    C = Rotation.from_euler("ZYX", [2.0, -0.1, 0.05]).as_matrix()
    b1, b2 = body(C)
    assert s.feed(Message(1.0, "mag", tuple(b2))) == []        # no accelerometer sample yet
    s.take_input(0.98, np.r_[-b1, 0.0, 0.0, 0.0])             # static: f_b = -g_b
    (out,) = s.feed(Message(1.0, "mag", tuple(b2), 5))
    assert out.t == 1.0 and out.line == 5 and out.sensor == "mag" and out.value.size == 0
    assert quat.angle_between(out.attitude, quat.from_matrix(C)) < 1e-12
    P, _ = attitude_covariance("improved_triad", b1, b2, G_N, M_N, np.eye(3) * 0.05**2, np.eye(3) * 0.09)
    np.testing.assert_allclose(out.attitude_cov, P, rtol=1e-9)
    assert s.feed(Message(1.1, "mag", ("x", 1.0, 2.0))) == [] and s.events[-1].kind == "no_fix"


def test_attitude_measurement():
    m = Attitude(AttitudeParams(), BuildContext(layout=L16))
    q_m = quat.from_euler(0.1, 0.2, -1.0)
    obs = m.observe(Message(0.0, "mag", tuple(q_m) + (1e-4, 0, 0, 2e-4, 0, 3e-4)))
    np.testing.assert_allclose(obs.R, np.diag([1e-4, 2e-4, 3e-4]))
    x = np.zeros(16)
    dth = np.array([0.01, -0.02, 0.005])
    x[6:10] = -quat.multiply(quat.exp(dth), q_m)              # sign of q irrelevant
    np.testing.assert_allclose(obs.model.h(x), dth, atol=1e-6)  # small-angle error, navigation frame
    np.testing.assert_allclose(obs.model.h(np.stack([x, x])), [dth, dth], atol=1e-6)


def test_quaternion_covariance_mapping():
    """G maps a navigation-frame error d theta to the quaternion: exp(d/2) (x) q - q ~ G d."""
    q = quat.from_euler(0.3, -0.2, 1.0)
    d = np.array([1e-6, -2e-6, 3e-6])
    np.testing.assert_allclose(quat.multiply(quat.exp(d), q) - q, error_to_quaternion(q) @ d, atol=1e-11)  # 2nd order
    P = covariance_in_state(q, np.diag([1e-4, 2e-4, 3e-4]))
    assert np.linalg.eigvalsh(P).min() > 0
