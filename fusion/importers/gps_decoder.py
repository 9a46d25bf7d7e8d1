"""Decoder ``gps_fields``: the ``gps`` lines ``fusion import`` writes -> one local-NED fix a line.

``fusion import`` writes a flight log's GPS as geodetic fields (``# fields gps lat lon alt vn ve vd hacc vacc
hdop fix nsat geoid``: deg, deg, m above mean sea level, NED velocity m/s, the receiver's horizontal and
vertical accuracy (1 sd, m), HDOP, fix type, satellites, geoid height above the WGS84 ellipsoid m). ArduPilot
logs have no geoid height (0) and, without GPA records, no accuracies (11 or 9 values). This
decoder turns each into the message the ``gps`` measurement model reads::

    pn pe pd vn ve hdop vdop satellites quality averaged hacc vacc

position in m, NED about the origin (paper 002 eqs. 5-6, by pymap3d on WGS84 with the ellipsoidal height
``alt + geoid``), velocity north/east in m/s, HDOP (VDOP not logged: nan), satellites, fix type as the
quality, 1 fix averaged, and the receiver's own accuracies (the ``gps`` model's ``accuracy: receiver``).
The first fix, the origin, carries its position only (velocity nan), as the ``nmea`` decoder's origin fix,
and so do the fixes of the next ``position_only_s`` seconds: the filter's initial position
(``initial.from_sensor``) is the latest fix before its start, and the scheduler takes a position from it;
the fixes after bring the velocity.

The origin is the config's ``origin``, else the first accepted fix (the recording's header ``origin``, to
which ``fusion import`` also refers the reference: docs/import.md), so a flight log started in the air
needs no static period. A fix below ``min_fix`` (2: 2-D, 3: 3-D) or with fewer than ``min_satellites``
is rejected (counted), never fused; a line of another layout is malformed. The fix type is a code, not a
scale: ``min_fix`` ranks the measured fixes 2-6 (2-D, 3-D, DGPS, RTK float, RTK fixed: PX4's
``sensor_gps.fix_type``, ArduPilot's GPS status), and 7 and 8 (PX4: 8 "extrapolated", the receiver's own
dead reckoning; MAVLink: 7 static, 8 PPP) are rejected unless ``fix_types`` lists them.
"""
from __future__ import annotations

import math
from typing import Any, ClassVar

from pydantic import Field, model_validator

from fusion.api import BuildContext, Decoder, MalformedMessage, Message, Params, RejectedMessage
from fusion.importers.gps_nmea_pair import NmeaPairs

FIELDS = ("lat", "lon", "alt", "vn", "ve", "vd", "hacc", "vacc", "hdop", "fix", "nsat", "geoid")
# The layouts the importers write, by their number of values: PX4 (with the geoid height), ArduPilot with
# GPA (accuracies, no geoid: 0), ArduPilot without GPA (no accuracies either).
MIN_FIX = 3          # a 3-D fix
MIN_SATELLITES = 6   # PX4 EKF2_REQ_NSATS default; the importers' header origin is the first fix passing both
LAYOUTS = {12: FIELDS, 11: FIELDS[:11], 9: ("lat", "lon", "alt", "vn", "ve", "vd", "hdop", "fix", "nsat"),
           # PX4 with samples whose velocity the receiver flags invalid: vok 0 there (position only)
           13: FIELDS + ("vok",)}


class Origin(Params):
    """A geodetic origin of the local NED frame (WGS84; altitude above mean sea level, as the log's GPS)."""

    lat_deg: float = Field(..., ge=-90, le=90)
    lon_deg: float = Field(..., ge=-180, le=360)
    alt_m: float = Field(0.0, description="m above mean sea level")


class GpsFieldsParams(Params):
    """YAML parameters of ``gps_fields``."""

    origin: Origin | None = Field(None, description="origin of the local NED frame; None: the first accepted fix")
    min_fix: int = Field(MIN_FIX, ge=1, le=6, description="lowest fix type used among 2: 2-D, 3: 3-D, 4: "
                         "DGPS, 5: RTK float, 6: RTK fixed; 7 and 8 (PX4 8: extrapolated) never pass (fix_types)")
    fix_types: list[int] | None = Field(None, min_length=1, description="the fix types used, exactly (e.g. "
                                        "[3, 4, 5, 6, 8] for a MAVLink source whose 8 is PPP); replaces min_fix")
    position_only_s: float = Field(0.0, ge=0, description="s after the origin fix during which fixes carry "
                                   "their position only (velocity nan): set it >= initial.align_s, the "
                                   "filter's initial fix (the latest before the start) being a position")
    min_satellites: int = Field(MIN_SATELLITES, ge=0, description="fewer satellites: rejected (PX4 EKF2_REQ_NSATS default 6)")

    @model_validator(mode="after")
    def _one_rule(self):
        if self.fix_types is not None and "min_fix" in self.model_fields_set:
            raise ValueError("give min_fix or fix_types (the exact list), not both")
        if self.fix_types is not None and any(not 1 <= f <= 8 for f in self.fix_types):
            raise ValueError(f"fix types are 1-8, got {self.fix_types}")
        return self


class GpsFieldsDecoder(Decoder):
    """Geodetic GPS fields (``fusion import``'s layout) -> local NED fix; see the module docstring."""

    name: ClassVar[str] = "gps_fields"
    Params: ClassVar[type[Params]] = GpsFieldsParams

    def __init__(self, params: GpsFieldsParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        p: GpsFieldsParams = self.params  # type: ignore[assignment]
        self.origin: tuple[float, float, float] | None = None   # lat deg, lon deg, ellipsoidal height m
        self.origin_source = "config" if p.origin is not None else "the first accepted fix"
        self._t0 = 0.0                                          # s, time of the origin fix
        self._fix_types = frozenset(p.fix_types) if p.fix_types is not None else frozenset(range(p.min_fix, 7))
        self.counters: dict[str, int] = {"fixes": 0, "rejected": 0}
        self._nmea = NmeaPairs()   # GGA + RMC lines of an import with --gps nmea (fusion.importers.gps_nmea_pair)

    def info(self) -> dict[str, Any]:
        """The origin used (deg, deg, m ellipsoidal) and where it came from, and the counters."""
        o = None if self.origin is None else {"lat_deg": self.origin[0], "lon_deg": self.origin[1],
                                              "alt_m": self.origin[2]}
        return {"origin": o, "origin_source": self.origin_source, **self.counters}

    def decode(self, message: Message) -> Message | None:
        import pymap3d  # at first use: start-up stays cheap

        p: GpsFieldsParams = self.params  # type: ignore[assignment]
        v = message.values
        if len(v) == 1 and isinstance(v[0], str) and v[0].startswith("$"):   # fusion import --gps nmea
            f = self._nmea.feed(v[0])
            if f is None:
                return None
        else:
            names = LAYOUTS.get(len(v))
            if names is None:
                raise MalformedMessage(f"gps_fields expects 13, 12, 11 or 9 values ({' '.join(FIELDS)}, as fusion "
                                       f"import writes them) or an NMEA sentence, got {len(v)}")
            try:
                f = dict(zip(names, (float(x) for x in v)))
            except (TypeError, ValueError):
                raise MalformedMessage(f"gps_fields: a value is not a number in {v!r}") from None
        lat, lon, alt, vn, ve = f["lat"], f["lon"], f["alt"], f["vn"], f["ve"]
        fix, nsat, hdop = f["fix"], f["nsat"], f["hdop"]
        if f.get("vok", 1.0) < 0.5:                       # the receiver said its velocity is not valid
            vn = ve = math.nan
        hacc, vacc, geoid = f.get("hacc", math.nan), f.get("vacc", math.nan), f.get("geoid", 0.0)
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 360.0) or not math.isfinite(alt):
            raise MalformedMessage(f"gps_fields: position out of range (lat {lat}, lon {lon}, alt {alt})")
        if fix not in self._fix_types or nsat < p.min_satellites:
            self.counters["rejected"] += 1
            need = (f"fix type in {sorted(self._fix_types)}" if p.fix_types is not None
                    else f"fix >= {p.min_fix} and <= 6 (7, 8: no measured fix)")
            raise RejectedMessage(f"gps_fields: fix type {fix:g} with {nsat:g} satellites (need {need}, "
                                  f"satellites >= {p.min_satellites})")
        h = alt + geoid                                   # ellipsoidal height (m)
        if self.origin is None:
            self._t0 = message.t
            if p.origin is not None:
                self.origin = (p.origin.lat_deg, p.origin.lon_deg, p.origin.alt_m + geoid)
            else:
                self.origin = (lat, lon, h)
        self.counters["fixes"] += 1
        n, e, d = pymap3d.geodetic2ned(lat, lon, h, *self.origin)
        if message.t - self._t0 <= p.position_only_s:   # the origin fix (and the initial window's): position
            vn = ve = math.nan
        return Message(message.t, message.sensor, (float(n), float(e), float(d), vn, ve, hdop, math.nan, nsat,
                                                   fix, 1.0, hacc, vacc), message.line)
