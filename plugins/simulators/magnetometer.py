"""Magnetometer simulator: the Earth's field in NED rotated into the body frame."""
from __future__ import annotations

import numpy as np
from pydantic import Field, field_validator

from fusion.simulate.base import SensorOutput, SensorSimulator, SimContext, SimParams, sample_times


class MagParams(SimParams):
    rate_hz: float = Field(6.0, gt=0, description="samples per second")
    declination_deg: float | None = Field(None, description="magnetic declination (deg, east of true north "
                                          "positive); none of the three: the IGRF at the scenario's origin "
                                          "and start_utc")
    inclination_deg: float | None = Field(None, ge=-90, le=90, description="inclination (deg, below the "
                                          "horizon positive: northern hemisphere)")
    intensity: float | None = Field(None, gt=0, description="total field (uT)")
    noise_sd: float = Field(0.2, ge=0, description="noise sd per axis (uT)")
    hard_iron: list[float] = Field([0.0, 0.0, 0.0], description="constant body-frame offset (uT)")
    disturbances: list[list] = Field(default_factory=list, description="[[start_s, length_s, [n, e, d]], ...]: "
                                     "an extra field (uT, NED) in these intervals (a nearby magnetic object)")

    @field_validator("hard_iron")
    @classmethod
    def _three(cls, v):
        if len(v) != 3:
            raise ValueError(f"expected 3 values, got {len(v)}")
        return v


def earth_field(declination_deg: float, inclination_deg: float, intensity: float) -> np.ndarray:
    """m_n (3,) in NED: F [cos I cos D, cos I sin D, sin I]."""
    D, I = np.radians(declination_deg), np.radians(inclination_deg)
    return intensity * np.array([np.cos(I) * np.cos(D), np.cos(I) * np.sin(D), np.sin(I)])


class MagnetometerSimulator(SensorSimulator):
    """3-axis magnetometer: fields ``mx my mz`` (uT, FRD body frame).

    ``m_b = C_n^b (m_n + d_n(t)) + h_b + n`` with the Earth field m_n from declination, inclination and
    intensity (NED), else the IGRF at the scenario's origin and start (fusion.geomag), optional disturbances d_n in time intervals, a hard-iron offset h_b and white noise.
    ``--noise off``: ``m_b = C_n^b m_n`` exactly (no hard iron, no disturbance, no noise)."""

    name = "magnetometer"
    Params = MagParams

    def fields(self, sim: SimContext) -> tuple[str, ...]:
        return ("mx", "my", "mz")

    def field(self, sim: SimContext) -> np.ndarray:
        """m_n (3,) uT NED: the parameters' field, else the IGRF at the scenario's origin and start."""
        p = self.params
        angles = (p.declination_deg, p.inclination_deg, p.intensity)
        if all(a is not None for a in angles):
            return earth_field(*angles)  # type: ignore[arg-type]
        from fusion.api import ConfigError
        if any(a is not None for a in angles):
            raise ConfigError(f"sensors.{self.context.sensor}: give all of declination_deg, inclination_deg and "
                              "intensity, or none (the IGRF at the scenario's origin and start_utc)")
        if sim.origin is None or sim.start_utc is None:
            raise ConfigError(f"sensors.{self.context.sensor}: no field given and the scenario has no origin: give "
                              "declination_deg, inclination_deg and intensity, or the scenario's origin (the IGRF "
                              "there)")
        from fusion.geomag import igrf_ned
        return igrf_ned(sim.origin[0], sim.origin[1], sim.origin[2], sim.start_utc, "uT")

    def header(self, sim: SimContext) -> list[str]:
        p = self.params
        s = self.context.sensor
        m = self.field(sim)
        return [f"{s} units: uT", f"{s} rate_hz: {p.rate_hz:g}",
                f"{s} earth_field_ned: {m[0]:.6f} {m[1]:.6f} {m[2]:.6f}",
                f"{s} noise_sd: {p.noise_sd if sim.noise else 0:g}"]

    def simulate(self, sim: SimContext) -> SensorOutput:
        p = self.params
        t = sample_times(p.rate_hz, sim.duration)
        kin = sim.kinematics(t)
        m_n = np.broadcast_to(self.field(sim), (len(t), 3)).copy()
        if sim.noise:
            for d in p.disturbances:
                if len(d) != 3 or len(d[2]) != 3:
                    from fusion.api import ConfigError
                    raise ConfigError(f"sensors.{self.context.sensor}.disturbances: each is "
                                      f"[start_s, length_s, [n, e, d]], got {d}")
                m_n[(t >= d[0]) & (t < d[0] + d[1])] += np.asarray(d[2], float)
        m_b = kin.rotation.apply(m_n, inverse=True)
        if sim.noise:
            m_b = m_b + np.asarray(p.hard_iron, float) + sim.rng.normal(0.0, p.noise_sd, m_b.shape)
        return SensorOutput(t, m_b.tolist())
