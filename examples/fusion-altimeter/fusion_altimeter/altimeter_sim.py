"""The altimeter's simulator, for ``fusion simulate`` scenarios (``type: altimeter``)."""
from __future__ import annotations

from pydantic import Field

from fusion.api import SensorOutput, SensorSimulator, SimParams, sample_times


class AltimeterSimParams(SimParams):
    rate_hz: float = Field(5.0, gt=0, description="samples per second")
    noise_sd: float = Field(0.3, ge=0, description="height noise sd (m)")
    offset: float = Field(0.0, description="height of the reference above the origin (m), as the model's")


class AltimeterSimulator(SensorSimulator):
    """Altimeter samples: field ``height`` (m, up) = offset - p_z of the trajectory, plus white noise."""

    name = "altimeter"
    Params = AltimeterSimParams

    def fields(self, sim):
        return ("height",)

    def simulate(self, sim):
        p = self.params
        t = sample_times(p.rate_hz, sim.duration)
        h = p.offset - sim.kinematics(t).p[:, 2]
        if sim.noise:
            h = h + sim.rng.normal(0.0, p.noise_sd, t.size)
        return SensorOutput(t, [(float(v),) for v in h])
