"""The Earth's main magnetic field from the International Geomagnetic Reference Field (IGRF-14, through the
``ppigrf`` package of the IAGA V-MOD working group, which publishes the IGRF coefficients).

``ppigrf`` (pure Python, IGRF-14 coefficients 1900-2030, maintained by IAGA V-MOD) was picked over ``pyigrf``
(one release, no tests) and ``pygeomag`` (the World Magnetic Model, 2020-2030 only): the same spherical
harmonic synthesis as the IGRF's reference Fortran program, agreeing with its published tables to the last
nT (tests/test_geomag.py). It imports pandas, so it is imported only when a field is computed.
"""
from __future__ import annotations

import datetime as _dt
import math

import numpy as np

from fusion.errors import ConfigError

#: nT per unit of each magnetometer unit a header may state (``# mag units: uT``)
UNITS_NT = {"nT": 1.0, "uT": 1e3, "µT": 1e3, "mG": 100.0, "G": 1e5, "gauss": 1e5, "T": 1e9}
#: the IGRF-14 model's validity (its secular variation is predictive to 2030)
VALID_YEARS = (1900, 2030)


def igrf_ned(lat_deg: float, lon_deg: float, height_m: float, when: _dt.datetime | _dt.date,
             units: str = "uT") -> np.ndarray:
    """IGRF main field (3,) in NED (north, east, down) at a geodetic place (WGS84 latitude and longitude in
    degrees, ellipsoidal height in m) and date, in ``units`` (a key of :data:`UNITS_NT`)."""
    if units not in UNITS_NT:
        raise ConfigError(f"magnetic field units {units!r}: expected one of {', '.join(UNITS_NT)}")
    if not (-90.0 <= lat_deg <= 90.0 and math.isfinite(lon_deg) and math.isfinite(height_m)):
        raise ConfigError(f"IGRF: place ({lat_deg}, {lon_deg}, {height_m} m) is not a geodetic position")
    when = when if isinstance(when, _dt.datetime) else _dt.datetime(when.year, when.month, when.day)
    if not VALID_YEARS[0] <= when.year < VALID_YEARS[1]:
        raise ConfigError(f"IGRF: date {when.date()} outside the model's {VALID_YEARS[0]}-{VALID_YEARS[1]}")
    import ppigrf

    if when.tzinfo is not None:
        when = when.astimezone(_dt.timezone.utc).replace(tzinfo=None)
    be, bn, bu = ppigrf.igrf(lon_deg, lat_deg, height_m / 1000.0, when)
    ned = np.array([float(np.ravel(bn)[0]), float(np.ravel(be)[0]), -float(np.ravel(bu)[0])])
    return ned / UNITS_NT[units]


def field_ned(declination_deg: float, inclination_deg: float, intensity: float) -> np.ndarray:
    """m_n (3,) in NED from declination D (east of true north), inclination I (below the horizon) and
    intensity F: ``F [cos I cos D, cos I sin D, sin I]``."""
    D, I = np.radians(declination_deg), np.radians(inclination_deg)
    return intensity * np.array([np.cos(I) * np.cos(D), np.cos(I) * np.sin(D), np.sin(I)])


def describe(m: np.ndarray) -> str:
    """``D +x.x deg, I +y.y deg, F z.z`` of a NED field (3,)."""
    m = np.asarray(m, float)
    h = math.hypot(m[0], m[1])
    return (f"declination {math.degrees(math.atan2(m[1], m[0])):+.1f} deg, inclination "
            f"{math.degrees(math.atan2(m[2], h)):+.1f} deg, intensity {float(np.linalg.norm(m)):.4g}")
