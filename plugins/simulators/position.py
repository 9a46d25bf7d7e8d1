"""Generic position-fix simulator (a camera, a total station, a solver's output)."""
from __future__ import annotations

import numpy as np
from pydantic import Field

from fusion.simulate.base import SensorOutput, SensorSimulator, SimContext, SimParams, sample_times


class PositionParams(SimParams):
    rate_hz: float = Field(1.0, gt=0, description="fixes per second")
    start_s: float = Field(0.0, ge=0, description="time of the first fix (s)")
    noise_sd: float | list[float] = Field(0.1, description="sd (m): one value, or one per axis")
    lever_arm: list[float] = Field([0.0, 0.0, 0.0], description="offset of the fixed point in the body (m, FRD)")
    dropout_prob: float = Field(0.0, ge=0, le=1, description="probability a fix is missing")
    outlier_prob: float = Field(0.0, ge=0, le=1, description="probability a fix is an outlier")
    outlier_sd: float = Field(2.0, ge=0, description="sd of an outlier's extra error per axis (m)")


class PositionSimulator(SensorSimulator):
    """Position fixes: fields ``x y z`` (m, NED), or ``x y`` in a 2-D scenario. The fixed point is the body
    origin + C_b^n lever_arm; white noise, outliers and dropouts; ``--noise off``: exact."""

    name = "position"
    Params = PositionParams

    def fields(self, sim: SimContext) -> tuple[str, ...]:
        return ("x", "y") if sim.dim == 2 else ("x", "y", "z")

    def simulate(self, sim: SimContext) -> SensorOutput:
        p = self.params
        t = sample_times(p.rate_hz, sim.duration, p.start_s)
        kin = sim.kinematics(t)
        arm = np.asarray(p.lever_arm, float)
        pos = kin.p + (kin.rotation.apply(arm) if np.any(arm) else 0.0)
        pos = pos[:, : sim.dim]
        r_drop, r_noise, r_out, r_out2 = sim.rng.spawn(4)
        keep = r_drop.random(len(t)) >= p.dropout_prob
        if sim.noise:
            sd = np.broadcast_to(np.asarray(p.noise_sd, float), (3,))[: sim.dim] if np.ndim(p.noise_sd) else \
                np.full(sim.dim, float(p.noise_sd))
            pos = pos + r_noise.normal(0.0, 1.0, pos.shape) * sd
            out = r_out.random(len(t)) < p.outlier_prob
            pos = pos + out[:, None] * r_out2.normal(0.0, p.outlier_sd, pos.shape)
        return SensorOutput(t[keep], pos[keep].tolist())
