"""kf: the linear Kalman filter."""
from __future__ import annotations

import numpy as np

from fusion.api import Belief, ConfigError, Gate, MeasurementModel, Params, ProcessModel, UpdateResult

from .base import KalmanBase, covariance_of, linear_predict, linearised_update
from .jacobian import process_jacobian


class KalmanFilter(KalmanBase):
    r"""Linear Kalman filter, for affine models ``x_k = F x_{k-1} + b(u) + w``, ``z = H x + c + v``.

    Prediction (paper 001 eqs. 9-10)::

        x^- = f(x, u, dt) = F x + b,   P^- = F P F^T + Q

    Update::

        y = z - H x^-,   S = H P^- H^T + R,   K = P^- H^T S^-1
        x^+ = x^- + K y,   P^+ = (I - K H) P^- (I - K H)^T + K R K^T   (Joseph form, symmetrised)

    F and H are the models' Jacobians (analytic, else central differences, exact for affine functions
    up to rounding). The process model must declare ``linear = True`` (ConfigError otherwise: use ekf,
    iekf, ukf or srukf); a measurement model is assumed affine. The result equals FilterPy's
    ``KalmanFilter`` (tests/filters/test_filterpy_reference.py).
    """

    name = "kf"

    class Params(Params):
        """The KF has no parameters."""

    def predict(self, belief: Belief, process: ProcessModel, u: np.ndarray | None, dt: float) -> Belief:
        if not process.linear:
            raise ConfigError(f"filter 'kf' needs a linear process model; process {process.name!r} is not "
                              "linear (linear = False): use ekf, iekf, ukf or srukf")
        self.process = process
        if dt == 0.0:
            return belief
        x = belief.x
        F = process_jacobian(process, x, u, dt)
        P1 = linear_predict(x, covariance_of(belief), F, process.Q(x, u, dt))
        self.counters["predicts"] += 1
        return Belief(belief.t + dt, process.normalize(process.f(x, u, dt)), P=P1)

    def update(self, belief: Belief, model: MeasurementModel, z: np.ndarray, R: np.ndarray,
               gate: Gate | None = None) -> UpdateResult:
        return linearised_update(self, belief, model, z, R, gate, max_iterations=1)
