"""GPS streams as NMEA 0183 sentences (``fusion import --gps nmea``): one GGA, GST and RMC a fix, as a
receiver sends them, for configs whose GPS goes through the ``nmea`` decoder (paper 002's system).

GGA: UTC time, latitude/longitude (ddmm.mmmmmmm, 1e-7 arc-minute: ~0.2 mm), fix quality (1 GPS, 2 DGPS,
4 RTK fixed, 5 RTK float), satellites, HDOP, altitude above mean sea level and the geoid's height above the
WGS84 ellipsoid (so altitude + separation is the ellipsoidal height). RMC: status A, speed over ground
(knots) and course (deg true) from the NED velocity, date. UTC: the log's ``start_utc`` plus t; without
it, t from midnight of 2000-01-01 (the sentences then carry no real date, only a consistent clock).
"""
from __future__ import annotations

import datetime as dt
import math

import numpy as np

from fusion.api import Stream

KNOT = 1852.0 / 3600.0   # m/s
_QUALITY = {3: 1, 4: 2, 5: 5, 6: 4}   # PX4 fix_type / ArduPilot Status (3-D, DGPS, RTK float, fixed) -> GGA quality
_USABLE = frozenset(_QUALITY)


def _checksum(body: str) -> str:
    c = 0
    for ch in body.encode("ascii"):
        c ^= ch
    return f"{c:02X}"


def _sentence(body: str) -> str:
    return f"${body}*{_checksum(body)}"


def _angle(deg: float, width: int) -> tuple[str, float]:
    a = abs(deg)
    d = int(a)
    m = (a - d) * 60.0
    if round(m, 7) >= 60.0:
        d, m = d + 1, 0.0
    return f"{d:0{width}d}{m:010.7f}", deg


def gga_rmc(t_utc: dt.datetime, lat: float, lon: float, alt: float, geoid: float, vn: float, ve: float,
            quality: int, nsat: int, hdop: float) -> tuple[str, str]:
    """The GGA and RMC sentences of one fix (angles in deg, heights in m, velocity in m/s)."""
    hms = t_utc.strftime("%H%M%S") + f".{t_utc.microsecond // 10000:02d}"
    la, _ = _angle(lat, 2)
    lo, _ = _angle(lon, 3)
    ns, ew = ("N" if lat >= 0 else "S"), ("E" if lon >= 0 else "W")
    hd = f"{hdop:.2f}" if math.isfinite(hdop) else ""
    gga = _sentence(f"GPGGA,{hms},{la},{ns},{lo},{ew},{quality},{nsat:02d},{hd},{alt:.3f},M,{geoid:.3f},M,,")
    spd = math.hypot(vn, ve) / KNOT
    crs = math.degrees(math.atan2(ve, vn)) % 360.0
    date = t_utc.strftime("%d%m%y")
    rmc = _sentence(f"GPRMC,{hms},A,{la},{ns},{lo},{ew},{spd:.3f},{crs:.2f},{date},,,A")
    return gga, rmc


def gst(t_utc: dt.datetime, hacc: float, vacc: float) -> str | None:
    """The GST sentence of a fix's accuracies (1 sd, m: latitude and longitude each ``hacc``, altitude
    ``vacc``), or None when the receiver gave none (0 or not finite)."""
    if not (math.isfinite(hacc) and hacc > 0 and math.isfinite(vacc) and vacc > 0):
        return None
    hms = t_utc.strftime("%H%M%S") + f".{t_utc.microsecond // 10000:02d}"
    return _sentence(f"GPGST,{hms},,{hacc:.3f},{hacc:.3f},0.0,{hacc:.3f},{hacc:.3f},{vacc:.3f}")


def as_nmea(s: Stream, start_utc: str | None, notes: list[str] | None = None) -> Stream:
    """The stream of GGA + RMC sentences (``# fields gps nmea``) of a numeric GPS stream. Only 3-D fixes
    and better (fix type 3-6) are written: a GGA carries no fix dimension, so a 2-D fix (its height not
    solved) or an extrapolated one (PX4 fix type 8) would reach the ``nmea`` decoder as an ordinary fix,
    its unsolved altitude fused and possibly the origin; the numeric route's ``min_fix`` 3 drops
    them as well. How many were left out is added to ``notes``."""
    f = {name: i for i, name in enumerate(s.fields)}
    v = np.asarray(s.values, float)
    base = (dt.datetime.fromisoformat(start_utc.replace("Z", "+00:00")) if start_utc
            else dt.datetime(2000, 1, 1, tzinfo=dt.timezone.utc))

    def col(name, default=math.nan):
        return v[:, f[name]] if name in f else np.full(len(v), default)

    lat, lon, alt = col("lat"), col("lon"), col("alt")
    geoid, vn, ve = col("geoid", 0.0), col("vn", 0.0), col("ve", 0.0)
    fix, nsat, hdop = col("fix", 3.0), col("nsat", 0.0), col("hdop")
    vok = col("vok", 1.0)      # a velocity the receiver flagged invalid: GGA only (a position-only epoch)
    hacc, vacc = col("hacc"), col("vacc")
    ts, rows = [], []
    usable = np.isin(fix, list(_USABLE))
    if notes is not None and not usable.all():
        kinds = ", ".join(f"{int(np.sum(fix[~usable] == k))} of type {int(k)}" for k in np.unique(fix[~usable]))
        notes.append(f"{s.sensor} as NMEA: {int(np.sum(~usable))} fix(es) not 3-D or better left out ({kinds}: a "
                     "GGA cannot say a height is unsolved or a fix extrapolated)")
    for k, t in enumerate(np.asarray(s.t, float).tolist()):
        if not usable[k]:
            continue
        when = base + dt.timedelta(seconds=t)
        gga, rmc = gga_rmc(when, lat[k], lon[k], alt[k], geoid[k], vn[k], ve[k],
                           _QUALITY[int(fix[k])], int(nsat[k]), hdop[k])
        acc = gst(when, hacc[k], vacc[k])
        for sentence in (gga, acc, rmc if vok[k] >= 0.5 else None):
            if sentence is not None:
                ts.append(t)
                rows.append((sentence,))
    meta = dict(s.meta)
    meta["units"] = "NMEA 0183 GGA + RMC a fix" + ("" if start_utc else " (UTC from 2000-01-01: the log gave no date)")
    return Stream(s.sensor, ("nmea",), np.array(ts), rows=rows, meta=meta)
