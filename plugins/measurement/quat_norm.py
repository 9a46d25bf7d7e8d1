"""Measurement ``quat_norm``: the quaternion-norm pseudo-observation ``e = 1 - ||q||`` (paper 002 eq. 9)."""
from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import Field

from fusion.api import Belief, BuildContext, ConfigError, MalformedMessage, MeasurementModel, Observation, Params


class QuatNormParams(Params):
    """YAML parameters of ``quat_norm``."""

    sd: float = Field(1e-3, gt=0, description="sd of the pseudo-observation (the additive noise of sec. 3 "
                      "that sets how fast the norm is pulled to 1)")
    block: str = Field("q", description="the quaternion block")


class QuatNorm(MeasurementModel):
    """Pseudo-observation of the quaternion norm (eq. 9): ``z = 0``, ``h(x) = 1 - ||q||``, R = sd^2, applied
    after every prediction (``rule = "after_predict"``, the fusion.api.PseudoMeasurement capability: the
    sensor gets no messages; configure it like any sensor, ``model: quat_norm``).

    With the process's ``renormalize: false`` it is what keeps ``|q|`` near 1 (the norm drifts through the
    updates' additive corrections); with renormalisation it still removes the variance along q from P
    (the direction the attitude cannot move). Jacobian analytic: ``dh/dq = -q^T / |q|``.
    """

    name: ClassVar[str] = "quat_norm"
    carries_R = True    # R = sd^2 of its own params
    Params: ClassVar[type[Params]] = QuatNormParams
    dim: int = 1
    rule: str = "after_predict"

    def __init__(self, params: QuatNormParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        layout = self.context.layout
        b = self.params.block  # type: ignore[attr-defined]
        if layout is None or b not in layout or layout.block(b).kind != "quaternion":
            raise ConfigError(f"quat_norm needs a quaternion block {b!r} in the state")
        self._q = layout[b]
        self.n = layout.n
        self._z = np.zeros(1)
        self._R = np.array([[self.params.sd ** 2]])  # type: ignore[attr-defined]

    def h(self, x: np.ndarray) -> np.ndarray:
        q = np.asarray(x, dtype=float)[..., self._q]
        return 1.0 - np.sqrt((q * q).sum(axis=-1, keepdims=True))

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        q = np.asarray(x, dtype=float)[self._q]
        H = np.zeros((1, self.n))
        H[0, self._q] = -q / np.sqrt(q @ q)
        return H

    def pseudo_observation(self, belief: Belief) -> Observation | None:
        return Observation(belief.t, self._z, self, self._R)

    def observe(self, message):
        raise MalformedMessage("quat_norm is a pseudo-observation (applied after each prediction); its sensor "
                               "takes no messages")
