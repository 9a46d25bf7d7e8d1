"""GPS simulator: NMEA GGA and RMC sentences from a geodetic origin (WGS84, pymap3d)."""
from __future__ import annotations

import datetime as _dt

import numpy as np
import pymap3d
from pydantic import Field

from fusion.api import ConfigError
from fusion.logformat import checksum
from fusion.simulate.base import SensorOutput, SensorSimulator, SimContext, SimParams, sample_times

KNOT = 1852.0 / 3600.0  # m/s


class GpsParams(SimParams):
    rate_hz: float = Field(1.0, gt=0, description="fixes per second")
    start_s: float = Field(0.0, ge=0, description="time of the first fix (s)")
    horizontal_sd: float = Field(2.0, ge=0, description="north and east position noise sd (m)")
    vertical_sd: float = Field(3.0, ge=0, description="down position noise sd (m)")
    correlation_time: float = Field(0.0, ge=0, description="position errors are first-order Gauss-Markov "
                                    "with this time constant (s); 0: white")
    velocity_sd: float = Field(0.1, ge=0, description="horizontal velocity noise sd (m/s), in RMC speed/course")
    lever_arm: list[float] = Field([0.0, 0.0, 0.0], description="antenna offset in the body frame (m, FRD)")
    lost_fixes: list[float] = Field(default_factory=list, description="times (s) of single fixes the receiver "
                                    "loses: GGA with fix quality 0 and RMC status V, no position")
    gaps: list[list[float]] = Field(default_factory=list, description="[[start_s, length_s], ...]: no "
                                    "sentences at all in these intervals")
    sentences: list[str] = Field(["GGA", "RMC"], description="which sentences, in order, each fix")
    satellites: int = Field(8, ge=0, le=99, description="number of satellites reported in GGA")
    hdop: float = Field(1.0, gt=0, description="HDOP reported in GGA")


def _degrees_minutes(a: float, width: int) -> str:
    """ddmm.mmmmmmm of a >= 0 deg; minutes that round to 60.0000000 carry into the degrees (3460.0000000 N
    is refused by the decoder as malformed)."""
    d = int(a)
    m = (a - d) * 60
    if round(m, 7) >= 60.0:
        d, m = d + 1, 0.0
    return f"{d:0{width}d}{m:010.7f}"


def _lat(deg: float) -> tuple[str, str]:
    return _degrees_minutes(abs(deg), 2), "N" if deg >= 0 else "S"


def _lon(deg: float) -> tuple[str, str]:
    return _degrees_minutes(abs(deg), 3), "E" if deg >= 0 else "W"


def nmea(body: str) -> str:
    """``$BODY*HH`` with the NMEA checksum (XOR of the bytes between ``$`` and ``*``)."""
    return f"${body}*{checksum(body)}"


class GpsSimulator(SensorSimulator):
    """GPS receiver: each fix is a ``$GPGGA`` and a ``$GPRMC`` sentence, one a line (``t,gps,$GPGGA,...*HH``).

    The antenna position (body origin + C_b^n lever_arm, NED) plus noise is converted to latitude,
    longitude (7 decimals of minutes, ~0.2 mm) and ellipsoidal height (GGA altitude with a geoid
    separation of 0, 3 decimals) about the scenario's ``origin`` with pymap3d (WGS84). RMC carries speed
    over ground (knots) and course (deg true), UTC from the scenario's ``start_utc``. Faults: single lost
    fixes (quality 0 / status V, empty position) and gaps with no sentences. ``--noise off``: exact
    positions and velocities (faults stay).
    """

    name = "gps"
    Params = GpsParams

    def fields(self, sim: SimContext) -> tuple[str, ...]:
        return ("nmea",)

    def header(self, sim: SimContext) -> list[str]:
        p = self.params
        s = self.context.sensor
        return [f"{s} rate_hz: {p.rate_hz:g}",
                f"{s} horizontal_sd: {p.horizontal_sd if sim.noise else 0:g}",
                f"{s} vertical_sd: {p.vertical_sd if sim.noise else 0:g}"]

    def _noise(self, rng, sd: float, n: int, dt: float) -> np.ndarray:
        tau = self.params.correlation_time
        w = rng.normal(0.0, 1.0, n)
        if tau <= 0 or n == 0:
            return sd * w
        phi = np.exp(-dt / tau)
        e = np.empty(n)
        e[0] = w[0]
        q = np.sqrt(1 - phi * phi)
        for k in range(1, n):
            e[k] = phi * e[k - 1] + q * w[k]
        return sd * e

    def simulate(self, sim: SimContext) -> SensorOutput:
        p = self.params
        if sim.origin is None:
            raise ConfigError(f"sensors.{self.context.sensor}: a gps needs the scenario's `origin` "
                              "(lat_deg, lon_deg, alt_m)")
        t = sample_times(p.rate_hz, sim.duration, p.start_s)
        keep = np.ones(len(t), bool)
        for g in p.gaps:
            if len(g) != 2 or g[1] <= 0:
                raise ConfigError(f"sensors.{self.context.sensor}.gaps: each gap is [start_s, length_s], got {g}")
            keep &= ~((t >= g[0]) & (t < g[0] + g[1]))
        lost = np.zeros(len(t), bool)
        for tl in p.lost_fixes:
            lost[np.argmin(np.abs(t - tl))] = True
        kin = sim.kinematics(t)
        arm = np.asarray(p.lever_arm, float)
        pos = kin.p + (kin.rotation.apply(arm) if np.any(arm) else 0.0)
        vel = kin.v + (kin.rotation.apply(np.cross(kin.w_b, arm)) if np.any(arm) else 0.0)
        n = len(t)
        if sim.noise:
            r_n, r_e, r_d, r_v = sim.rng.spawn(4)
            dt = 1.0 / p.rate_hz
            pos = pos + np.column_stack([self._noise(r_n, p.horizontal_sd, n, dt),
                                         self._noise(r_e, p.horizontal_sd, n, dt),
                                         self._noise(r_d, p.vertical_sd, n, dt)])
            vel = vel + np.column_stack([r_v.normal(0, p.velocity_sd, (n, 2)), np.zeros(n)])
        lat0, lon0, h0 = sim.origin
        lat, lon, h = pymap3d.ned2geodetic(pos[:, 0], pos[:, 1], pos[:, 2], lat0, lon0, h0)
        lat, lon, h = np.atleast_1d(lat), np.atleast_1d(lon), np.atleast_1d(h)
        out_t, out_v = [], []
        for k in np.flatnonzero(keep):
            utc = sim.start_utc + _dt.timedelta(seconds=float(t[k]))
            hms = f"{utc:%H%M%S}.{utc.microsecond // 10000:02d}"
            la, ns = _lat(float(lat[k]))
            lo, ew = _lon(float(lon[k]))
            sog = float(np.hypot(vel[k, 0], vel[k, 1])) / KNOT
            cog = float(np.degrees(np.arctan2(vel[k, 1], vel[k, 0]))) % 360.0
            for s in p.sentences:
                if s == "GGA":
                    body = (f"GPGGA,{hms},,,,,0,00,99.9,,M,,M,," if lost[k] else
                            f"GPGGA,{hms},{la},{ns},{lo},{ew},1,{p.satellites:02d},{p.hdop:.1f},"
                            f"{float(h[k]):.3f},M,0.0,M,,")
                elif s == "RMC":
                    body = (f"GPRMC,{hms},V,,,,,,,{utc:%d%m%y},,,N" if lost[k] else
                            f"GPRMC,{hms},A,{la},{ns},{lo},{ew},{sog:.3f},{cog:.2f},{utc:%d%m%y},,,A")
                else:
                    raise ConfigError(f"sensors.{self.context.sensor}.sentences: unknown {s!r} (GGA, RMC)")
                out_t.append(t[k])
                out_v.append((nmea(body),))
        return SensorOutput(np.array(out_t), out_v)
