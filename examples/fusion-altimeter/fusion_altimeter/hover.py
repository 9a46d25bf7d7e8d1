"""A process model: a hovering vehicle, constant velocity with the velocity pulled back to rest
(first-order Gauss-Markov, time constant ``tau``)."""
from __future__ import annotations

import numpy as np
from pydantic import Field

from fusion.api import Params, ProcessModel, StateLayout


class HoverParams(Params):
    tau: float = Field(5.0, gt=0.0, description="velocity time constant (s)")
    sigma_v: float = Field(0.5, gt=0.0, description="steady-state velocity sd per axis (m/s)")


class Hover(ProcessModel[HoverParams]):
    """Hovering vehicle, state ``p:3 v:3`` (m, m/s, NED): ``p' = p + tau (1 - a) v``, ``v' = a v`` with
    a = exp(-dt / tau); velocity noise keeps its steady-state sd ``sigma_v`` (m/s), the discrete
    Gauss-Markov Q = sigma_v^2 (1 - a^2) on v (position noise neglected). Linear: the kf accepts it."""

    name = "hover"
    Params = HoverParams
    layout = StateLayout.parse("p:3 v:3")
    linear = True

    def _F(self, dt: float) -> np.ndarray:
        a = np.exp(-dt / self.params.tau)
        F = np.eye(6)
        F[:3, 3:] = self.params.tau * (1.0 - a) * np.eye(3)
        F[3:, 3:] = a * np.eye(3)
        return F

    def f(self, x, u, dt):
        """States (..., 6) after dt (s)."""
        return np.asarray(x, dtype=float) @ self._F(dt).T

    def jacobian(self, x, u, dt):
        return self._F(dt)

    def Q(self, x, u, dt):
        a = np.exp(-dt / self.params.tau)
        Q = np.zeros((6, 6))
        Q[3:, 3:] = self.params.sigma_v ** 2 * (1.0 - a * a) * np.eye(3)
        return Q
