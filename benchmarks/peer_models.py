"""Plain-numpy models and the peer libraries' filters on them, for ``bench_peers.py``.

Each peer steps its own model written here in plain numpy (not the project's model objects): the
constant-velocity + ranges model of paper 001 (eqs. 3-4, 6) in ``d`` dimensions (n = 2d, state
``[p (d), v (d)]``), and the 16-state strapdown INS of paper 000 (eqs. 33-52, Euler integration, state
``[p v q ba bw]``, quaternion Hamilton scalar-first body-to-nav, NED, gravity +z) with a position fix
through a lever arm (eq. 53). SI units throughout.

A peer filter is ``(step, estimate)``: ``step(z)`` runs one predict over dt then one update with the
measurement z (m,); ``estimate()`` gives the current (x (n,), P (n, n)).
"""
from __future__ import annotations

from typing import Callable

import numpy as np

Step = tuple[Callable[[np.ndarray], None], Callable[[], tuple[np.ndarray, np.ndarray]]]


# ---- models -------------------------------------------------------------------------------------

def cv_matrices(d: int, q: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """F and Q of the d-axis constant-velocity model, Q_axis = q [[dt^3/3, dt^2/2], [dt^2/2, dt]]."""
    I = np.eye(d)
    F = np.block([[I, dt * I], [np.zeros((d, d)), I]])
    Q = q * np.block([[dt ** 3 / 3 * I, dt ** 2 / 2 * I], [dt ** 2 / 2 * I, dt * I]])
    return F, Q


def ranges(x: np.ndarray, beacons: np.ndarray) -> np.ndarray:
    """Ranges (m,) from the position x[:d] to each beacon (m, d)."""
    return np.sqrt(((x[: beacons.shape[1]] - beacons) ** 2).sum(axis=1))


def ranges_jacobian(x: np.ndarray, beacons: np.ndarray) -> np.ndarray:
    d = beacons.shape[1]
    diff = x[:d] - beacons
    H = np.zeros((beacons.shape[0], x.shape[0]))
    H[:, :d] = diff / np.sqrt((diff ** 2).sum(axis=1))[:, None]
    return H


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def _dcm(q: np.ndarray) -> np.ndarray:
    """C_b^n of q / |q| (Hamilton, scalar first)."""
    w, x, y, z = q
    C = np.array([[w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z]])
    return C / (q @ q)


def ins_f(x: np.ndarray, u: np.ndarray, dt: float, g: float = 9.80665) -> np.ndarray:
    """One Euler step of the INS with the IMU sample u = [a (3, m/s^2), w (3, rad/s)] (eqs. 34-52)."""
    a, w = u[:3] - x[10:13], u[3:] - x[13:16]
    half = w * (0.5 * dt)
    s = np.sqrt(half @ half)
    dq = np.concatenate(([np.cos(s)], half * (np.sin(s) / s if s > 0 else 1.0)))
    acc = _dcm(x[6:10]) @ a + np.array([0.0, 0.0, g])
    return np.concatenate((x[0:3] + x[3:6] * dt, x[3:6] + acc * dt, _quat_mul(x[6:10], dq), x[10:16]))


def ins_Q(x: np.ndarray, dt: float, na: float, nw: float, nba: float, nbw: float, qnv: float) -> np.ndarray:
    """Process noise of :func:`ins_f` from the white-noise densities (accelerometer na, gyro nw, bias random
    walks nba, nbw) and the variance qnv along q: the double integrator for p, v (isotropic accelerometer
    noise, so C N^2 C^T = N^2 I), ``(dt/4) nw^2 Xi(q) Xi(q)^T + qnv q q^T/|q|^2`` for q, ``N^2 dt`` for the biases."""
    w, a, b, c = x[6:10]
    Xi = np.array([[-a, -b, -c], [w, -c, b], [c, w, -a], [-b, a, w]])
    Q = np.zeros((16, 16))
    I3 = np.eye(3) * na ** 2 * dt
    Q[0:3, 0:3], Q[0:3, 3:6], Q[3:6, 0:3], Q[3:6, 3:6] = I3 * dt ** 2 / 3, I3 * dt / 2, I3 * dt / 2, I3
    q = x[6:10]
    Q[6:10, 6:10] = dt / 4 * nw ** 2 * Xi @ Xi.T + qnv * np.outer(q, q) / (q @ q)
    Q[10:13, 10:13] = np.eye(3) * nba ** 2 * dt
    Q[13:16, 13:16] = np.eye(3) * nbw ** 2 * dt
    return Q


def position_h(x: np.ndarray, lever: np.ndarray) -> np.ndarray:
    """Position of the antenna at the lever arm (body frame, m) from the IMU (eq. 53)."""
    return x[0:3] + _dcm(x[6:10]) @ lever


# ---- peers --------------------------------------------------------------------------------------

def filterpy_ukf(fx, hx, x0, P0, Q, R, dt, alpha, beta, kappa) -> Step:
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    n, m = x0.shape[0], R.shape[0]
    ukf = UnscentedKalmanFilter(n, m, dt, hx, lambda x, dt_: fx(x, dt_), MerweScaledSigmaPoints(n, alpha, beta, kappa))
    ukf.x, ukf.P, ukf.Q, ukf.R = x0.copy(), P0.copy(), Q, R

    def step(z):
        ukf.predict()
        ukf.update(z)
    return step, lambda: (ukf.x.copy(), ukf.P.copy())


def filterpy_ekf(F, Q, hx, hjac, x0, P0, R) -> Step:
    from filterpy.kalman import ExtendedKalmanFilter

    n, m = x0.shape[0], R.shape[0]
    ekf = ExtendedKalmanFilter(n, m)
    ekf.x, ekf.P, ekf.F, ekf.Q, ekf.R = x0.copy(), P0.copy(), F, Q, R

    def step(z):
        ekf.predict()
        ekf.update(z, hjac, hx)
    return step, lambda: (ekf.x.copy(), ekf.P.copy())


def _columns(fun):
    """fun on each column of X (n, k) -> (m, k): a model written for one state, as Stone Soup calls it on all
    sigma points at once."""
    return lambda X: np.stack([fun(c) for c in X.T], axis=1)


def _stonesoup_models(fxc, hxc, n: int, m: int, dt: float, Q: np.ndarray, R: np.ndarray):
    """A Stone Soup transition model (Q fixed) and measurement model calling fxc(X, dt) and hxc(X)."""
    from stonesoup.base import Property
    from stonesoup.models.measurement.nonlinear import NonLinearGaussianMeasurement
    from stonesoup.models.transition.nonlinear import GaussianTransitionModel, TimeVariantModel
    from stonesoup.types.array import CovarianceMatrix, StateVector, StateVectors

    def columns(fun, state):
        X = np.asarray(state.state_vector, dtype=float)
        return StateVectors(fun(X)) if X.shape[1] > 1 else StateVector(fun(X)[:, 0])

    class Transition(GaussianTransitionModel, TimeVariantModel):
        noise: np.ndarray = Property(doc="Q (n, n)")

        @property
        def ndim_state(self):
            return n

        def function(self, state, noise=False, **kwargs):
            return columns(lambda X: fxc(X, dt), state)

        def covar(self, **kwargs):
            return CovarianceMatrix(self.noise)

    class Measurement(NonLinearGaussianMeasurement):
        @property
        def ndim_meas(self):
            return m

        def function(self, state, noise=False, **kwargs):
            return columns(hxc, state)

    return Transition(noise=Q), Measurement(ndim_state=n, mapping=tuple(range(n)), noise_covar=CovarianceMatrix(R))


def stonesoup_ukf(fx, hx, x0, P0, Q, R, dt, alpha, beta, kappa, fx_cols=None, hx_cols=None,
                  normalize=None) -> Step:
    """Stone Soup's UnscentedKalmanPredictor/Updater on a transition and a measurement model that call
    the plain functions. Stone Soup evaluates a model on all sigma points at once (states as columns):
    ``fx_cols(X, dt)``, ``hx_cols(X)`` when given, otherwise ``fx(x, dt)``, ``hx(x)`` column by column.
    ``normalize(x)`` (in place) after predict and update, if given."""
    from datetime import datetime, timedelta

    from stonesoup.predictor.kalman import UnscentedKalmanPredictor
    from stonesoup.types.array import CovarianceMatrix, StateVector
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import UnscentedKalmanUpdater

    fxc = fx_cols or (lambda X, dt_: _columns(lambda x: fx(x, dt_))(X))
    trans, meas = _stonesoup_models(fxc, hx_cols or _columns(hx), x0.shape[0], R.shape[0], dt, Q, R)
    pred = UnscentedKalmanPredictor(trans, alpha=alpha, beta=beta, kappa=kappa)
    upd = UnscentedKalmanUpdater(meas, alpha=alpha, beta=beta, kappa=kappa)
    t0 = datetime(2026, 1, 1)
    box = {"s": GaussianState(StateVector(x0.copy()), CovarianceMatrix(P0.copy()), timestamp=t0), "k": 0}
    tick = timedelta(seconds=dt)

    def step(z):
        box["k"] += 1
        t = t0 + box["k"] * tick
        prior = pred.predict(box["s"], timestamp=t)
        if normalize is not None:                       # in place on the state vector (n, 1)
            normalize(prior.state_vector[:, 0])
        det = Detection(StateVector(z), timestamp=t, measurement_model=meas)
        box["s"] = upd.update(SingleHypothesis(prior, det))
        if normalize is not None:
            normalize(box["s"].state_vector[:, 0])
    return step, lambda: (np.asarray(box["s"].state_vector, dtype=float).ravel(),
                          np.asarray(box["s"].covar, dtype=float))


def fusion_single(name: str, process, model, x0, P0, u, R, dt, alpha, beta, kappa) -> Step:
    """One of the project's filters (registry name) on the project's own model objects."""
    from fusion import testing

    params = {"alpha": alpha, "beta": beta, "kappa": kappa} if name in ("ukf", "srukf") else {}
    flt = testing.build("filter", name, params)
    box = [flt.initial_belief(0.0, x0, P0)]

    def step(z):
        box[0] = flt.update(flt.predict(box[0], process, u, dt), model, z, R).belief
    return step, lambda: (box[0].x.copy(), np.asarray(box[0].cov, dtype=float))
