"""The reference magnetic field m_n (NED) of a magnetometer, in this order: the config's (``field_ned``, or
``declination_deg`` / ``inclination_deg`` / ``intensity``), the recording header's ``# SENSOR
earth_field_ned: N E D`` (in the header's ``# SENSOR units``), or the IGRF (fusion.geomag) at the
recording's origin and date (``# origin`` and ``# start_utc``, else the log's first NMEA fix). Used by the
``magnetometer`` model and the ``triad`` solver; what was used goes into the run summary's ``info``.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from fusion import geomag
from fusion.api import ConfigError
from fusion.world import of_context


def config_field(params: Any) -> np.ndarray | None:
    """m_n from the component's own parameters, or None when it gives none."""
    if getattr(params, "field_ned", None) is not None:
        return np.asarray(params.field_ned, dtype=float)
    angles = (params.declination_deg, params.inclination_deg, params.intensity)
    if all(a is not None for a in angles):
        return geomag.field_ned(*angles)
    return None


def resolve_field(params: Any, context: Any) -> tuple[np.ndarray, dict[str, Any]]:
    """(m_n (3,) NED in the sensor's units, info) for the sensor ``context.sensor``; info's ``source`` is
    ``config``, ``recording header`` or ``IGRF``, with where it came from. ConfigError when none applies."""
    sensor = getattr(context, "sensor", None) or "?"
    m = config_field(params)
    if m is not None:
        return m, {"source": "config", "field_ned": _rounded(m), "field": geomag.describe(m)}
    world = of_context(context)
    if world is not None and sensor in world.mag_field:
        d = world.mag_field[sensor]
        return d.value.copy(), {"source": "recording header", "where": d.where, "field_ned": _rounded(d.value),
                                "field": geomag.describe(d.value)}
    if world is not None and world.origin is not None and world.date is not None:
        units = world.mag_units.get(sensor, "uT")
        lat, lon, h = world.origin.value
        m = geomag.igrf_ned(lat, lon, h, world.date.value, units)
        return m, {"source": "IGRF-14 (ppigrf)", "where": f"origin {world.origin.where}, date {world.date.where}",
                   "at": f"{lat:.5f} {lon:.5f} {h:.0f} m, {world.date.value.date().isoformat()}",
                   "units": units, "field_ned": _rounded(m), "field": geomag.describe(m)}
    have = "no recording header known ahead (a stream)" if world is None else (
        f"the recording {world.path} declares no '# {sensor} earth_field_ned' and "
        + ("no origin" if world.origin is None else "no date") + " (no '# origin' / '# start_utc' line, no NMEA RMC fix)")
    raise ConfigError(f"magnetometer ({sensor}): the reference magnetic field is unknown: {have}; give field_ned, "
                      "or declination_deg, inclination_deg and intensity (a World Magnetic Model / IGRF value "
                      "for the place and date)")


def _rounded(m: np.ndarray) -> list[float]:
    return [round(float(v), 4) for v in m]
