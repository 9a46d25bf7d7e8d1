"""N independent 4-state filters (constant velocity + 4 ranges) stepped together, for ``bench_peers.py``:
the project's batched engine (fusion.batch, what ``fusion sweep`` runs), dynamax's filters under
``jax.vmap`` (CPU, float64) and FilterPy in a Python loop. Every filter conditions on its measurement
then predicts (dynamax's order), from its own x0, on its own ranges."""
from __future__ import annotations

from typing import Callable

import numpy as np

import peer_models as pm

BEACONS = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0]])
Q_DENSITY, DT, R_SD = 0.5, 0.1, 0.05
P0 = np.diag([0.5, 0.5, 0.1, 0.1])


def problem(N: int, T: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """x0 (N, 4) and the ranges Z (N, T, 4) of N targets moving at constant velocity."""
    rng = np.random.default_rng(seed)
    truth0 = np.array([5.0, 4.0, 1.0, 0.5]) + rng.normal(0, [1.0, 1.0, 0.2, 0.2], (N, 4))
    F, _ = pm.cv_matrices(2, Q_DENSITY, DT)
    Z = np.empty((N, T, 4))
    x = truth0.copy()
    for t in range(T):
        Z[:, t] = np.sqrt(((x[:, None, :2] - BEACONS) ** 2).sum(axis=2)) + rng.normal(0, R_SD, (N, 4))
        x = x @ F.T
    x0 = truth0 + rng.normal(0, 0.3, (N, 4))
    return x0, Z


def _ranges_model():
    """The project's 4-range model with ``jacobian_batch`` (N, 4, 4), as the ``range`` plugin has it for
    sweeps (without it the batched EKF calls the Jacobian once per filter)."""
    from fusion import testing

    class Ranges(testing.RangeMeasurement):
        def jacobian_batch(self, x):
            diff = x[:, None, :2] - BEACONS
            H = np.zeros((x.shape[0], 4, 4))
            H[:, :, :2] = diff / np.sqrt((diff * diff).sum(axis=-1))[..., None]
            return H
    return Ranges(Ranges.Params(beacons=BEACONS.tolist(), n=4))


def fusion_batch(name: str, x0: np.ndarray, Z: np.ndarray, alpha, beta, kappa) -> Callable[[], tuple]:
    """A run of the project's batched filter: returns the final (x (N, 4), P (N, 4, 4))."""
    from fusion import testing
    from fusion.batch import make_batch_filter

    params = {"alpha": alpha, "beta": beta, "kappa": kappa} if name in ("ukf", "srukf") else {}
    bf = make_batch_filter(testing.build("filter", name, params))
    proc = testing.ConstantVelocity(testing.ConstantVelocity.Params(dims=2, q=Q_DENSITY))
    model = _ranges_model()
    R = np.eye(4) * R_SD ** 2

    def run():
        b = bf.initial_belief(0.0, x0, P0)
        for t in range(Z.shape[1]):
            b = bf.update(b, model, Z[:, t], R, None).belief
            if t < Z.shape[1] - 1:
                b = bf.predict(b, proc, None, DT)
        return b.x, b.cov
    return run


def dynamax_batch(name: str, x0: np.ndarray, Z: np.ndarray, alpha, beta, kappa) -> Callable[[], tuple]:
    """dynamax's UKF or EKF (jit of vmap over the N filters); returns the last filtered (x, P)."""
    import jax
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    from dynamax.nonlinear_gaussian_ssm import (ParamsNLGSSM, UKFHyperParams, extended_kalman_filter,
                                                unscented_kalman_filter)

    F, Q = (jnp.asarray(a) for a in pm.cv_matrices(2, Q_DENSITY, DT))
    beacons = jnp.asarray(BEACONS)
    R = jnp.eye(4) * R_SD ** 2

    def h(x):
        return jnp.sqrt(((x[:2] - beacons) ** 2).sum(axis=1))

    def one(m0, ys):
        params = ParamsNLGSSM(m0, jnp.asarray(P0), lambda x: F @ x, Q, h, R)
        fields = ["filtered_means", "filtered_covariances"]
        if name == "ukf":
            post = unscented_kalman_filter(params, ys, UKFHyperParams(alpha, beta, kappa), output_fields=fields)
        else:
            post = extended_kalman_filter(params, ys, output_fields=fields)
        return post.filtered_means[-1], post.filtered_covariances[-1]

    fn = jax.jit(jax.vmap(one))
    xj, Zj = jnp.asarray(x0), jnp.asarray(Z)

    def run():
        m, P = fn(xj, Zj)
        m.block_until_ready()
        return np.asarray(m), np.asarray(P)
    return run


def filterpy_loop(name: str, x0: np.ndarray, Z: np.ndarray, alpha, beta, kappa, r_scale=1.0) -> Callable[[], tuple]:
    """FilterPy's UKF or EKF, one filter after the other, on the plain-numpy model."""
    F, Q = pm.cv_matrices(2, Q_DENSITY, DT)
    R = np.eye(4) * R_SD ** 2 * r_scale

    def run():
        xs, Ps = [], []
        for i in range(x0.shape[0]):
            if name == "ukf":
                from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
                f = UnscentedKalmanFilter(4, 4, DT, lambda x: pm.ranges(x, BEACONS), lambda x, dt: F @ x,
                                          MerweScaledSigmaPoints(4, alpha, beta, kappa))
                f.x, f.P, f.Q, f.R = x0[i].copy(), P0.copy(), Q, R
                f.sigmas_f = f.points_fn.sigma_points(f.x, f.P)   # update first: its points from x0, P0
                for t in range(Z.shape[1]):
                    f.update(Z[i, t])
                    if t < Z.shape[1] - 1:
                        f.predict()
            else:
                from filterpy.kalman import ExtendedKalmanFilter
                f = ExtendedKalmanFilter(4, 4)
                f.x, f.P, f.F, f.Q, f.R = x0[i].copy(), P0.copy(), F, Q, R
                for t in range(Z.shape[1]):
                    f.update(Z[i, t], lambda x: pm.ranges_jacobian(x, BEACONS), lambda x: pm.ranges(x, BEACONS))
                    if t < Z.shape[1] - 1:
                        f.predict()
            xs.append(f.x.copy())
            Ps.append(f.P.copy())
        return np.array(xs), np.array(Ps)
    return run
