"""Process ``static_orientation``: the attitude held constant up to a random walk (paper 003 sec. 5.2).

State ``q:4``: Hamilton quaternion, scalar first, body-to-navigation (C_b^n). The transition is the
identity (the paper's Phi = I); the process noise is a random walk of the attitude by small body-frame
angles with sd ``angle_sd_deg`` per step (one firing, ``step_s``)::

    q(k+1) = q(k) (x) exp([0, w] / 2),  w ~ N(0, s^2 I3)  ->  Q = (s^2 / 4) Xi(q) Xi(q)^T + norm_sd^2 q q^T

over ``dt / step_s`` steps. Why a quaternion and not the paper's roll, pitch, yaw (eq. 18): roll-pitch-yaw
needs the pitch kept in [-pi/2, pi/2], angle wrapping in the filter's mean and residual, and breaks down at
pitch +-pi/2 where only roll +- yaw is defined; the random-walk robot of sec. 6.2 tumbles through any
attitude. A quaternion has no singularity, its block is what the framework scores attitude with (truth
``qw qx qy qz``, ``attitude_rmse_deg``), and the small-angle noise above is the paper's 0.57 deg in roll,
pitch and yaw per firing to first order. The norm direction of q is unobservable (every model divides by
|q|^2); the mean is renormalised after each update and ``norm_sd`` keeps P positive definite along it.
"""
from __future__ import annotations

import numpy as np
from pydantic import Field

from fusion import quaternion as quat
from fusion.api import Block, Params, ProcessModel, StateLayout


def attitude_noise(q: np.ndarray, angle_var: float, norm_var: float) -> np.ndarray:
    """Quaternion covariance (4, 4) of a small body-frame rotation with variance ``angle_var`` (rad^2) per
    axis about q (4,), plus ``norm_var`` along q itself."""
    q = quat.normalize(np.asarray(q, float))
    X = quat.xi(q)
    return (angle_var / 4.0) * (X @ X.T) + norm_var * np.outer(q, q)


class StaticOrientation(ProcessModel):
    """Attitude random walk (paper 003 sec. 5.2, identity transition); state ``q:4`` (unit quaternion,
    body-to-navigation). Params: ``angle_sd_deg`` per step in each axis, ``step_s`` the step (a firing),
    ``norm_sd`` the noise along q (unobservable direction, for a positive definite P)."""

    name = "static_orientation"

    class Params(Params):
        angle_sd_deg: float = Field(0.57, ge=0.0, description="deg per step about each body axis (paper: 0.57 "
                                    "in roll, pitch and yaw per firing)")
        step_s: float = Field(0.225, gt=0.0, description="s per step (one beacon firing)")
        norm_sd: float = Field(1e-3, gt=0.0, description="sd along q itself per step (no physical meaning)")

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        self.layout = StateLayout([Block("q", 4, "quaternion")])
        self._var = np.deg2rad(self.params.angle_sd_deg) ** 2
        self._nvar = self.params.norm_sd ** 2

    def f(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        return np.array(x, dtype=float, copy=True)

    def jacobian(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        return np.eye(4)

    def Q(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        n = max(dt, 0.0) / self.params.step_s
        return attitude_noise(x, n * self._var, n * self._nvar)

    # normalize: ProcessModel's (the layout's unit quaternion block q)
