"""The GGA (+ GST) + RMC sentences of ``fusion import --gps nmea`` read back as the geodetic fields of the
``gps_fields`` decoder, so one config reads a log imported either way (the decoder sees ``# fields gps
nmea`` lines: one sentence a line, the GGA then the RMC of one fix at one time).

GST (when the log had the receiver's accuracies): ``hacc`` the larger of the latitude and longitude sd,
``vacc`` the altitude sd (m). GGA: latitude, longitude (deg), altitude above mean sea level and geoid separation (m), fix quality,
satellites, HDOP; RMC: speed over ground (knots) and course (deg true) -> north and east velocity (m/s). A
GGA without its RMC (the importer writes none when the receiver flagged the velocity invalid) is a
position-only fix, emitted when the next GGA comes. GGA quality -> the fix type the importers write (1 GPS:
3-D, 2 DGPS: 4, 5 RTK float: 5, 4 RTK fixed: 6; others: 0, rejected by the fix test).
"""
from __future__ import annotations

import math

from fusion.api import MalformedMessage

KNOT = 1852.0 / 3600.0   # m/s
_FIX = {1: 3, 2: 4, 5: 5, 4: 6}


class NmeaPairs:
    """Gathers one fix's GGA and RMC; :meth:`feed` returns the fields of a completed fix or None."""

    def __init__(self):
        self._gga: dict | None = None

    def feed(self, sentence: str) -> dict | None:
        """The fix (``lat lon alt vn ve hdop fix nsat geoid``, velocity nan when unknown, and ``t`` the GGA's
        log time key) completed by ``sentence``, else None. MalformedMessage for a sentence that is not a
        GGA or RMC pynmea2 reads."""
        import pynmea2

        try:
            msg = pynmea2.parse(sentence, check=True)
        except (pynmea2.ParseError, pynmea2.ChecksumError, ValueError, AttributeError) as exc:
            raise MalformedMessage(f"gps_fields: not an NMEA sentence it reads ({exc})") from None
        kind = getattr(msg, "sentence_type", "")
        if kind == "GGA":
            done, self._gga = self._gga, _gga(msg)
            return done
        if kind == "GST":        # the fix's accuracies (1 sd, m), written between its GGA and RMC
            if self._gga is not None and getattr(msg, "timestamp", None) == self._gga["hms"]:
                try:
                    self._gga["hacc"] = max(float(msg.std_dev_latitude), float(msg.std_dev_longitude))
                    self._gga["vacc"] = float(msg.std_dev_altitude)
                except (TypeError, ValueError):
                    pass
            return None
        if kind == "RMC":
            gga, self._gga = self._gga, None
            if gga is None or getattr(msg, "timestamp", None) != gga["hms"]:
                return None        # an RMC without its GGA: no position
            try:
                spd, crs = float(msg.spd_over_grnd) * KNOT, math.radians(float(msg.true_course))
            except (TypeError, ValueError):
                return gga
            gga["vn"], gga["ve"] = spd * math.cos(crs), spd * math.sin(crs)
            return gga
        raise MalformedMessage(f"gps_fields: reads GGA, GST and RMC sentences, got {kind or sentence[:6]!r}")


def _gga(msg) -> dict:
    def num(v, default=math.nan):
        try:
            return float(v)
        except (TypeError, ValueError):
            return default

    quality = int(num(msg.gps_qual, 0))
    return {"hms": msg.timestamp, "lat": num(msg.latitude), "lon": num(msg.longitude), "alt": num(msg.altitude),
            "geoid": num(msg.geo_sep, 0.0), "vn": math.nan, "ve": math.nan, "hdop": num(msg.horizontal_dil),
            "fix": float(_FIX.get(quality, 0)), "nsat": num(msg.num_sats, 0.0)}
