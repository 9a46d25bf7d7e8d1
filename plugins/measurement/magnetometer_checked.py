"""Measurement ``magnetometer_checked``: the ``magnetometer`` model with a field-magnitude and dip check.

A local magnetic disturbance (steel, a motor, a phone) changes the field the sensor reads; the filter's chi2
gate sees it only once the error exceeds the attitude's own uncertainty, and a slow disturbance can pull the
heading first. Two checks that need no attitude reject a sample before the update (counted rejected, with
the reason), as Sabatini (IEEE TBME 53(7), 2006) detects a disturbed field and PX4 EKF2's EKF2_MAG_CHECK
(field strength and inclination) does:

* magnitude: ``| |m_b| / |m_n| - 1 | > max_intensity_error`` (the Earth's field has one intensity);
* dip: the angle between the field and the horizontal, measured in the body frame against the gravity
  direction ``d_b = -f_b / |f_b|`` of the held IMU sample (fusion.api.UsesInput): ``asin(m_b . d_b / |m_b|)``
  against the reference inclination ``asin(m_n,down / |m_n|)``; rejected beyond ``max_dip_error_deg``.
  Skipped while ``| |f| - g |`` exceeds ``dip_accel_tolerance`` (a moving body's f is no gravity direction).

The reference m_n is the ``magnetometer`` model's (config, recording header or IGRF). Units: the field's
(e.g. uT), FRD body frame, NED reference.
"""
from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from pydantic import Field

from fusion.api import BuildContext, Message, Observation, Params, RejectedMessage

from .magnetometer import Magnetometer, MagnetometerParams


class MagnetometerCheckedParams(MagnetometerParams):
    """YAML parameters of ``magnetometer_checked``: those of ``magnetometer`` and the two checks."""

    max_intensity_error: float | None = Field(0.1, gt=0, description="largest relative error of |m_b| "
                                              "against the reference intensity (none: no check)")
    max_dip_error_deg: float | None = Field(5.0, gt=0, description="largest error of the measured dip angle "
                                            "(deg; none: no check)")
    dip_accel_tolerance: float = Field(1.0, gt=0, description="m/s^2: the dip is checked only while the held "
                                       "specific force's norm is within this of g")
    gravity: float = Field(9.80665, gt=0, le=30, description="g (m/s^2) for the dip check's stillness test")


class MagnetometerChecked(Magnetometer):
    """``magnetometer`` (``z = C_n^b(q) m_n``) whose samples pass a magnitude and a dip check first (module
    docstring); reads the IMU's specific force through ``take_input``."""

    name: ClassVar[str] = "magnetometer_checked"
    Params: ClassVar[type[Params]] = MagnetometerCheckedParams

    def __init__(self, params: MagnetometerCheckedParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        self._f: np.ndarray | None = None

    def take_input(self, t: float | None, u: np.ndarray | None) -> None:
        """The held IMU sample (fusion.api.UsesInput): its specific force (m/s^2, FRD)."""
        self._f = None if u is None else np.asarray(u, dtype=float)[:3]

    def why_disturbed(self, z: np.ndarray) -> str | None:
        """Why the sample z (3,) (field units, FRD) fails a check, or None when it passes (or m_n is unknown)."""
        if self.m_n is None or self.direction_only:
            return None
        p: MagnetometerCheckedParams = self.params  # type: ignore[assignment]
        nz, nm = float(np.linalg.norm(z)), float(np.linalg.norm(self.m_n))
        if p.max_intensity_error is not None and abs(nz / nm - 1.0) > p.max_intensity_error:
            return (f"field intensity {nz:.4g} against the reference {nm:.4g} ({100 * (nz / nm - 1):+.0f} %, "
                    f"max_intensity_error {p.max_intensity_error:g}): a magnetic disturbance")
        f = self._f
        if p.max_dip_error_deg is None or f is None or nz == 0.0:
            return None
        nf = float(np.linalg.norm(f))
        if nf == 0.0 or abs(nf - p.gravity) > p.dip_accel_tolerance:
            return None
        dip = math.degrees(math.asin(max(-1.0, min(1.0, float(-f @ z) / (nf * nz)))))
        ref = math.degrees(math.asin(float(self.m_n[2]) / nm))
        if abs(dip - ref) > p.max_dip_error_deg:
            return (f"dip {dip:.1f} deg against the reference {ref:.1f} deg (max_dip_error_deg "
                    f"{p.max_dip_error_deg:g}): a magnetic disturbance")
        return None

    def observe(self, message: Message) -> Observation | None:
        obs = super().observe(message)
        if obs is None:
            return None
        why = self.why_disturbed(np.asarray(message.floats(), dtype=float))
        if why is not None:
            raise RejectedMessage(f"magnetometer_checked: {why}")
        return obs
