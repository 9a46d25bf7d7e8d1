"""iekf: the iterated extended Kalman filter (paper 003)."""
from __future__ import annotations

import numpy as np
from pydantic import Field

from fusion.api import Belief, Gate, MeasurementModel, Params, UpdateResult

from .base import linearised_update
from .ekf import ExtendedKalmanFilter


class IteratedExtendedKalmanFilter(ExtendedKalmanFilter):
    r"""Iterated EKF: the EKF prediction; the update re-linearises h about the updated estimate
    (Gauss-Newton on the MAP cost, Bell & Cathey 1993), as paper 003 does for its arrival-time and
    orientation filters (eqs. 9-11, 18-19)::

        x_0 = x^-
        H_i = dh/dx (x_i),   S_i = H_i P^- H_i^T + R,   K_i = P^- H_i^T S_i^-1
        x_{i+1} = x^- + K_i (z - h(x_i) - H_i (x^- - x_i))
        stop when max|x_{i+1} - x_i| <= tolerance or after max_iterations
        P^+ = (I - K H) P^- (I - K H)^T + K R K^T   with the last K, H (Joseph form)

    The fixed point is a stationary point of ``|x - x^-|^2_{P^-1} + |z - h(x)|^2_{R^-1}`` (the MAP
    estimate for Gaussian prior and noise). With ``max_iterations = 1`` it is the EKF. The reported
    innovation, S, NIS and the gate decision are the prior's (iteration 0). ``UpdateResult.iterations``
    is the number of iterations done (the run sums them in its ``update_iterations`` counter).
    """

    name = "iekf"

    class Params(Params):
        """Iteration control of the update."""

        max_iterations: int = Field(10, ge=1, description="Gauss-Newton iterations at most (1 = EKF)")
        tolerance: float = Field(1e-6, ge=0.0, description="stop when max|x_{i+1} - x_i| <= tolerance "
                                                             "(state units)")

    def update(self, belief: Belief, model: MeasurementModel, z: np.ndarray, R: np.ndarray,
               gate: Gate | None = None) -> UpdateResult:
        p = self.params
        return linearised_update(self, belief, model, z, R, gate, max_iterations=p.max_iterations,
                                 tolerance=p.tolerance)
