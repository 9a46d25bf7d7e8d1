"""kf: the linear Kalman filter."""
from __future__ import annotations

import numpy as np

from fusion.api import Belief, ConfigError, Params, ProcessModel

from .ekf import ExtendedKalmanFilter


class KalmanFilter(ExtendedKalmanFilter):
    # The same predict and update as the EKF (exact for affine models); only the check of the process differs.

    r"""Linear Kalman filter, for affine models ``x_k = F x_{k-1} + b(u) + w``, ``z = H x + c + v``.

    Prediction (paper 001 eqs. 9-10)::

        x^- = f(x, u, dt) = F x + b,   P^- = F P F^T + Q

    Update::

        y = z - H x^-,   S = H P^- H^T + R,   K = P^- H^T S^-1
        x^+ = x^- + K y,   P^+ = (I - K H) P^- (I - K H)^T + K R K^T   (Joseph form, symmetrised)

    F and H are the models' Jacobians (analytic, else central differences, exact for affine functions
    up to rounding). The rule for what it accepts: the process model and every measurement model must
    declare ``linear = True`` (f and h affine in x); wiring refuses any other with a ConfigError naming the
    config's ``filter:`` line (use ekf, iekf, ukf or srukf), and ``predict`` refuses a non-linear process
    model given directly. The result equals FilterPy's
    ``KalmanFilter`` (tests/filters/test_filterpy_reference.py).
    """

    name = "kf"
    linear_only = True

    class Params(Params):
        """The KF has no parameters."""

    def predict(self, belief: Belief, process: ProcessModel, u: np.ndarray | None, dt: float) -> Belief:
        if not process.linear:
            raise ConfigError(f"filter 'kf' needs a linear process model; process {process.name!r} is not "
                              "linear (linear = False): use ekf, iekf, ukf or srukf")
        return super().predict(belief, process, u, dt)
