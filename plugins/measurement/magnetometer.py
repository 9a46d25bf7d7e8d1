"""Measurement ``magnetometer``: the Earth's field seen in the body frame, ``h = C_n^b(q) m_n`` (paper 002 sec. 2.3)."""
from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import Field, model_validator

from fusion import quaternion as quat
from fusion.api import BuildContext, ConfigError, MalformedMessage, MeasurementModel, Message, Observation, Params


def earth_field(declination_deg: float, inclination_deg: float, intensity: float) -> np.ndarray:
    """m_n (3,) in NED from declination D (east of true north), inclination I (below the horizon) and
    intensity F: ``F [cos I cos D, cos I sin D, sin I]``."""
    D, I = np.radians(declination_deg), np.radians(inclination_deg)
    return intensity * np.array([np.cos(I) * np.cos(D), np.cos(I) * np.sin(D), np.sin(I)])


class FieldParams(Params):
    """The local reference field: ``field_ned`` or declination / inclination / intensity (a World
    Magnetic Model / IGRF value for the place and date)."""

    field_ned: tuple[float, float, float] | None = Field(None, description="m_n (NED, the sensor's units, e.g. uT)")
    declination_deg: float | None = Field(None, ge=-180, le=180, description="east of true north positive")
    inclination_deg: float | None = Field(None, ge=-90, le=90, description="below the horizon positive")
    intensity: float | None = Field(None, gt=0, description="total field (the sensor's units, e.g. uT)")

    @model_validator(mode="after")
    def _one_way(self):
        angles = (self.declination_deg, self.inclination_deg, self.intensity)
        if self.field_ned is None and any(a is None for a in angles):
            raise ValueError("give field_ned, or declination_deg, inclination_deg and intensity")
        if self.field_ned is not None and any(a is not None for a in angles):
            raise ValueError("give field_ned or the declination/inclination/intensity, not both")
        if self.field_ned is not None and not np.any(self.field_ned):
            raise ValueError("field_ned must not be zero")
        return self

    def field(self) -> np.ndarray:
        if self.field_ned is not None:
            return np.asarray(self.field_ned, dtype=float)
        return earth_field(self.declination_deg, self.inclination_deg, self.intensity)  # type: ignore[arg-type]


class MagnetometerParams(FieldParams):
    """YAML parameters of ``magnetometer``."""

    direction_only: bool = Field(False, description="measure the unit vector m_b / |m_b| (insensitive to the "
                                 "intensity; noise sd then in rad)")


_FLIP = np.array([1.0, -1.0, -1.0, -1.0])


class Magnetometer(MeasurementModel):
    """Three-axis magnetometer, ``z = C_n^b(q) m_n`` (FRD body frame, units of m_n), the direct vector
    measurement (the alternative to the TRIAD attitude measurement, ``solvers.triad``).

    ``C_n^b = C_b^n(q)^T = C_b^n(q*)`` (computed from q / |q|), so ``dh/dq = rotate_jacobian(q*, m_n)
    diag(1, -1, -1, -1)`` (analytic; no sensitivity along q). A disturbed field (a vehicle, a bridge)
    shows as a large NIS: use a chi2 gate. ``direction_only`` measures ``m_b / |m_b|`` against
    ``C_n^b m_n / |m_n|`` instead.
    """

    name: ClassVar[str] = "magnetometer"
    Params: ClassVar[type[Params]] = MagnetometerParams
    dim: int = 3

    def __init__(self, params: MagnetometerParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        layout = self.context.layout
        if layout is None or "q" not in layout or layout.block("q").kind != "quaternion":
            raise ConfigError("magnetometer needs a state with an attitude quaternion block 'q'")
        self._q = layout["q"]
        self.n = layout.n
        m = self.params.field()  # type: ignore[attr-defined]
        self.direction_only = bool(self.params.direction_only)  # type: ignore[attr-defined]
        self.m_n = m / np.linalg.norm(m) if self.direction_only else m

    def h(self, x: np.ndarray) -> np.ndarray:
        """Predicted field (..., 3) in the body frame for states x (..., n)."""
        q = np.asarray(x, dtype=float)[..., self._q]
        return quat.rotate(q * _FLIP, self.m_n)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """dh/dx (3, n) at x (n,)."""
        q = np.asarray(x, dtype=float)[self._q]
        H = np.zeros((3, self.n))
        H[:, self._q] = quat.rotate_jacobian(q * _FLIP, self.m_n) * _FLIP
        return H

    def observe(self, message: Message) -> Observation | None:
        """Observation of a sample ``mx my mz`` (FRD)."""
        z = message.floats()
        if z.shape != (3,) or not np.all(np.isfinite(z)):
            raise MalformedMessage(f"magnetometer expects 3 finite values (mx my mz), got {message.values!r}")
        if self.direction_only:
            nz = float(np.linalg.norm(z))
            if nz == 0.0:
                raise MalformedMessage("magnetometer: zero field")
            z = z / nz
        return Observation(message.t, z, self)
