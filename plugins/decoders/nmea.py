"""Decoder ``nmea``: NMEA 0183 sentences (pynmea2) -> one local-NED GPS fix per epoch (paper 002 eqs. 5-6).

A receiver sends several sentences per fix (GGA: position, fix quality, satellites, HDOP; RMC: status,
speed and course over ground; optionally VTG: the same velocity; GSA: the dilutions of precision). This
decoder checks each sentence's checksum, gathers one epoch's sentences (by their UTC time, sentences
without a time joining the epoch being gathered, or the next one when they come before its first timed
sentence, as a u-blox receiver sends VTG before GGA) and, when the epoch's ``epoch`` sentences are all in,
emits one message, stamped at the log time of the sentence that completed the epoch (a logger that
stamps lines on arrival spreads a burst over up to a few hundred ms at 4800 baud: the fix is then that
much late: give the GPS sensor a ``time_offset`` of minus that spread, or an ``epoch`` of the sentences
sent first)::

    pn pe pd vn ve hdop vdop satellites quality averaged

position in m (local NED about the origin), horizontal velocity in m/s (NED, from speed and course;
``nan`` when the epoch has none), HDOP and VDOP (``nan`` when not sent), satellites used, GGA fix
quality, and how many fixes were averaged into it (1, or N for the origin fix below). The ``gps``
measurement model turns it into an observation.

Geodetic to NED (eqs. 5-6): pymap3d (WGS84) converts latitude, longitude and ellipsoidal height
(GGA altitude above the geoid + geoid separation) to NED about the origin, which is either given
(``origin: {lat_deg, lon_deg, alt_m}``) or, as the paper does (sec. 3.1), the mean of the fixes of the
static start: the valid fixes of the first ``origin_s`` seconds are averaged in ECEF, the mean becomes
the origin, and one position fix at the origin (NED 0, ``averaged`` = N) is emitted at the end of the
window (the filter's initial position, ``initial.from_sensor``). ``origin`` / ``origin_source`` /
``info()`` tell which origin was used.

The window is the static start, not only a duration: a fix whose speed over ground (RMC, VTG) is above
``static_speed`` is moving and is never averaged. It ends the window early (a GPS stream that starts after
the IMU, so that its first ``origin_s`` seconds run into the drive): the static fixes before it make the
origin, and the moving fix itself is emitted with its velocity and its own sd (``averaged`` = 1), so the
filter starts where the vehicle is, at the speed it has, instead of at the origin at rest. A stream
without a static fix (the first valid fix already moving) takes that fix as the origin, emitted the same
way. Either case is told once in ``events`` (a ``warning``, taken by :meth:`take_events`), in
``origin_source`` and in ``counters['moving_start']``. Without a speed (an epoch of GGA alone) the window
is the duration alone.

Counted, never fused: a bad or missing checksum and a sentence pynmea2 cannot parse raise
MalformedMessage (counted ``malformed``); an epoch without a valid fix (GGA quality 0, RMC status V, an
empty position) raises RejectedMessage (counted ``rejected``), once per epoch. GGA fix quality is a code,
not a scale (NMEA 0183: 0 invalid, 1 GPS, 2 DGPS, 3 PPS, 4 RTK fixed, 5 RTK float, 6 estimated / dead
reckoning, 7 manual input, 8 simulation): ``min_quality`` ranks the measured fixes 1-5 only, and 6-8,
which are no measurement (a receiver in a tunnel keeps sending its own extrapolation as quality 6), are
rejected unless ``qualities`` lists them. An epoch left incomplete
when the next one starts is dropped and counted in ``counters['incomplete']``.
"""
from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from pydantic import Field, field_validator, model_validator

from fusion.api import BuildContext, Decoder, Event, MalformedMessage, Message, Params, RejectedMessage

KNOT = 1852.0 / 3600.0   # m/s
# GGA fix quality codes that are no measurement (NMEA 0183): used only when ``qualities`` lists them
NOT_MEASURED = {6: "estimated (dead reckoning)", 7: "manual input", 8: "simulation"}
_KNOWN = ("GGA", "RMC", "VTG", "GSA")


class OriginSpec(Params):
    """A geodetic origin of the local NED frame (WGS84)."""

    lat_deg: float = Field(..., ge=-90, le=90)
    lon_deg: float = Field(..., ge=-180, le=360)
    alt_m: float = Field(0.0, description="ellipsoidal height (m)")


class NmeaParams(Params):
    """YAML parameters of ``nmea``."""

    origin: OriginSpec | None = Field(None, description="origin of the local NED frame; None: the mean of "
                                      "the fixes of the first origin_s seconds (paper 002 sec. 3.1)")
    origin_s: float = Field(0.0, ge=0, description="s of valid fixes averaged into the origin when none is "
                            "given (the static start); 0: the first valid fix is the origin")
    epoch: list[str] = Field(["GGA", "RMC"], min_length=1, description="sentences that make one epoch "
                             "complete (the fix is emitted when all of them are in)")
    min_quality: int = Field(1, ge=1, le=5, description="lowest GGA fix quality used among the measured "
                             "fixes 1 GPS, 2 DGPS, 3 PPS, 4 RTK fixed, 5 RTK float (4: 4 and 5 pass); 6 "
                             "dead reckoning, 7 manual and 8 simulation never pass (see qualities)")
    qualities: list[int] | None = Field(None, min_length=1, description="the GGA fix qualities used, "
                                        "exactly (e.g. [1, 2, 4, 5]); replaces min_quality; list 6 to fuse a "
                                        "receiver's dead reckoning")
    min_satellites: int = Field(4, ge=0, description="fewer satellites than this: the fix is rejected")
    static_speed: float = Field(0.5, gt=0, description="m/s: a fix with a higher speed over ground is moving: "
                                "it ends the origin's window and is never averaged into the origin (5x a "
                                "receiver's ~0.1 m/s velocity noise at rest)")

    @field_validator("qualities")
    @classmethod
    def _codes(cls, v: list[int] | None) -> list[int] | None:
        if v is not None and any(not 1 <= q <= 8 for q in v):
            raise ValueError(f"GGA fix qualities are 1-8 (0 is no fix), got {v}")
        return v

    @model_validator(mode="after")
    def _one_rule(self):
        if self.qualities is not None and "min_quality" in self.model_fields_set:
            raise ValueError("give min_quality or qualities (the exact list), not both")
        return self

    @field_validator("epoch")
    @classmethod
    def _known(cls, v: list[str]) -> list[str]:
        v = [s.upper() for s in v]
        bad = [s for s in v if s not in _KNOWN]
        if bad:
            raise ValueError(f"unknown sentence type(s) {bad}; known: {list(_KNOWN)}")
        if "GGA" not in v:
            raise ValueError("an epoch needs GGA (the only sentence with height, quality and HDOP)")
        return v


def _num(value: Any) -> float:
    """A pynmea2 field as float (nan when empty or not a number)."""
    if value is None or value == "":
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def _minutes_ok(field: str, degree_digits: int) -> bool:
    """ddmm.mmm / dddmm.mmm with minutes below 60."""
    try:
        return 0.0 <= float(field[degree_digits:]) < 60.0
    except ValueError:
        return False


_TIMED = frozenset(("GGA", "RMC"))   # the sentences that carry the epoch's UTC time


class NmeaDecoder(Decoder):
    """NMEA GGA + RMC (+ VTG, GSA) via pynmea2, one local-NED fix per epoch; see the module docstring.

    The message's value is the raw sentence (``t,gps,$GPGGA,...*HH`` in the log format). Output
    fields: ``pn pe pd vn ve hdop vdop satellites quality averaged`` (m, NED; m/s; -; -; -; -; -; count).
    """

    name: ClassVar[str] = "nmea"
    Params: ClassVar[type[Params]] = NmeaParams
    FIELDS: ClassVar[tuple[str, ...]] = ("pn", "pe", "pd", "vn", "ve", "hdop", "vdop", "satellites",
                                         "quality", "averaged")

    def __init__(self, params: NmeaParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        p: NmeaParams = self.params  # type: ignore[assignment]
        self._need = frozenset(p.epoch)
        self._qualities = (frozenset(p.qualities) if p.qualities is not None
                           else frozenset(range(p.min_quality, 6)))
        self.origin: tuple[float, float, float] | None = None
        self.origin_source = "config" if p.origin is not None else f"mean of the fixes of the first {p.origin_s:g} s"
        if p.origin is not None:
            self.origin = (p.origin.lat_deg, p.origin.lon_deg, p.origin.alt_m)
        self._epoch: dict[str, Any] = {}
        self._key: Any = None
        self._avg: list[np.ndarray] = []      # ECEF of the fixes averaged into the origin
        self._window_t0: float | None = None  # the first GPS message's time: the static start's window opens
        self._origin_ecef: tuple | None = None  # (origin, its ECEF) for _ned
        self._wgs84: Any = None                 # pymap3d's WGS-84 Ellipsoid, made with _origin_ecef
        self.counters: dict[str, int] = {"epochs": 0, "invalid": 0, "incomplete": 0, "origin_fixes": 0}
        self.events: list[Event] = []          # a moving start's warning, until take_events()

    # ------------------------------------------------------------------ public
    def info(self) -> dict[str, Any]:
        """The origin used (deg, deg, m) and where it came from, and the epoch counters."""
        o = None if self.origin is None else {"lat_deg": self.origin[0], "lon_deg": self.origin[1], "alt_m": self.origin[2]}
        return {"origin": o, "origin_source": self.origin_source, **self.counters}

    def take_events(self) -> list[Event]:
        """The events since the last call (a moving start's ``warning``), forgotten once taken."""
        events, self.events = self.events, []
        return events

    def decode(self, message: Message) -> Message | None:
        if self._window_t0 is None:
            # the origin's window is the first origin_s seconds of the GPS stream, valid fixes or not: a
            # receiver whose first fixes are bad must not average the fixes of the drive that follows
            self._window_t0 = float(message.t)
        sentence = self._parse(message)
        kind = sentence.sentence_type
        if kind not in _KNOWN:
            return None                      # GSV, GLL, ZDA, proprietary: nothing this decoder fuses
        key = getattr(sentence, "timestamp", None) if kind in ("GGA", "RMC") else None
        if key is not None and self._key is not None and key != self._key and self._epoch:
            if self._epoch.keys() & _TIMED:
                self.counters["incomplete"] += 1  # the previous epoch never completed
                self._epoch = {}
            # else only sentences without a time wait (a VTG or GSA sent before this epoch's GGA or RMC, as a
            # u-blox receiver orders them): they belong to this epoch; dropping them would make every fix of
            # a [GGA, VTG] epoch wait for the next second's VTG, 1 s late
        if key is not None:
            self._key = key
        self._epoch[kind] = sentence
        if not self._need <= self._epoch.keys():
            return None
        epoch, self._epoch = self._epoch, {}
        self.counters["epochs"] += 1
        return self._fix(message, epoch)

    # ------------------------------------------------------------------ internals
    @staticmethod
    def _parse(message: Message):
        if len(message.values) != 1 or not isinstance(message.values[0], str):
            raise MalformedMessage(f"nmea: expected one NMEA sentence, got {message.values!r}")
        text = message.values[0].strip()
        if not text.startswith("$"):
            raise MalformedMessage(f"nmea: not an NMEA sentence: {text[:40]!r}")
        import pynmea2  # at first use: every installed plugin module is imported at start-up

        try:
            return pynmea2.parse(text, check=True)
        except pynmea2.ChecksumError as exc:
            raise MalformedMessage(f"nmea: {exc.args[0]}") from None
        except (pynmea2.ParseError, ValueError, TypeError, AttributeError) as exc:
            raise MalformedMessage(f"nmea: cannot parse {text[:40]!r}: {exc.args[0] if exc.args else exc}") from None

    def _ned(self, pymap3d, lat: float, lon: float, h: float) -> tuple[float, float, float]:
        """NED (m) of a fix (deg, deg, m ellipsoidal) from the origin: pymap3d.geodetic2ned's own steps
        (geodetic2ecef of both, uvw2enu of the difference), the origin's ECEF computed once (the same
        numbers, much of the call saved), with the WGS-84 ellipsoid object made once."""
        if self._origin_ecef is None or self._origin_ecef[0] != self.origin:
            # pymap3d's default ellipsoid, built once (geodetic2ecef builds it at every call without ell=)
            self._wgs84 = pymap3d.Ellipsoid.from_name("wgs84")
            self._origin_ecef = (self.origin, pymap3d.geodetic2ecef(*self.origin, ell=self._wgs84))  # type: ignore[misc]
        x2, y2, z2 = self._origin_ecef[1]
        x1, y1, z1 = pymap3d.geodetic2ecef(lat, lon, h, ell=self._wgs84)
        east, north, up = pymap3d.uvw2enu(x1 - x2, y1 - y2, z1 - z2, self.origin[0], self.origin[1])  # type: ignore[index]
        return north, east, -up

    def _fix(self, message: Message, epoch: dict[str, Any]) -> Message | None:
        import pymap3d  # at first use (start-up stays cheap for configs without GPS)

        p: NmeaParams = self.params  # type: ignore[assignment]
        gga = epoch["GGA"]
        qual = _num(gga.gps_qual)          # a pynmea2 field costs a __getattr__ a read: read each once
        quality = int(qual) if math.isfinite(qual) else 0
        sats = _num(gga.num_sats)
        rmc = epoch.get("RMC")
        why = None
        if quality not in self._qualities:
            kind = NOT_MEASURED.get(quality)
            why = f"GGA fix quality {quality}" + (f" ({kind}: not a measured fix)" if kind else "")
        elif rmc is not None and rmc.status != "A":
            why = f"RMC status {rmc.status!r}"
        elif not gga.lat or not gga.lon or not math.isfinite(_num(gga.altitude)):
            why = "GGA without a position"
        elif math.isfinite(sats) and sats < p.min_satellites:
            why = f"{sats:.0f} satellites (< {p.min_satellites})"
        if why is not None:
            self.counters["invalid"] += 1
            raise RejectedMessage(f"nmea: no valid fix ({why})")
        try:
            lat, lon = float(gga.latitude), float(gga.longitude)
        except (TypeError, ValueError):
            raise MalformedMessage("nmea: GGA latitude/longitude not numbers") from None
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0) or not (
                _minutes_ok(gga.lat, 2) and _minutes_ok(gga.lon, 3)):
            raise MalformedMessage(f"nmea: GGA position out of range ({gga.lat} {gga.lat_dir}, {gga.lon} {gga.lon_dir})")
        sep = _num(gga.geo_sep)
        h = _num(gga.altitude) + (sep if math.isfinite(sep) else 0.0)   # ellipsoidal height
        vn = ve = math.nan
        vel = rmc if rmc is not None else None
        knots = _num(vel.spd_over_grnd) if vel is not None else math.nan
        if vel is not None and math.isfinite(knots):
            speed, course = knots * KNOT, _num(vel.true_course)
        elif "VTG" in epoch and math.isfinite(_num(epoch["VTG"].spd_over_grnd_kmph)):
            speed, course = _num(epoch["VTG"].spd_over_grnd_kmph) / 3.6, _num(epoch["VTG"].true_track)
        else:
            speed, course = math.nan, math.nan
        if math.isfinite(speed):
            if not math.isfinite(course):
                course = 0.0 if speed == 0.0 else math.nan
            c = math.radians(course)
            vn, ve = speed * math.cos(c), speed * math.sin(c)
        hdop = _num(gga.horizontal_dil)
        vdop = _num(epoch["GSA"].vdop) if "GSA" in epoch else math.nan
        gsa_hdop = _num(epoch["GSA"].hdop) if "GSA" in epoch else math.nan
        if math.isfinite(gsa_hdop):
            hdop = gsa_hdop
        averaged = 1.0
        if self.origin is None and math.isfinite(speed) and speed > p.static_speed:
            return self._moving_start(pymap3d, message, (lat, lon, h), speed,
                                      (vn, ve, hdop, vdop, sats, float(quality)))
        if self.origin is None:
            ecef = np.array(pymap3d.geodetic2ecef(lat, lon, h), dtype=float)
            if not self._avg and p.origin_s > 0 and message.t - self._window_t0 >= p.origin_s:  # type: ignore[operator]
                # no valid fix in the window: this one alone is the origin, and the summary says so
                self.origin_source = (f"the first valid fix, at {message.t:.3f} s (no valid fix in the first "
                                      f"{p.origin_s:g} s of GPS messages)")
            self._avg.append(ecef)
            self.counters["origin_fixes"] += 1
            if message.t - self._window_t0 < p.origin_s:   # type: ignore[operator]
                return None
            mean = np.mean(self._avg, axis=0)
            self.origin = tuple(float(v) for v in pymap3d.ecef2geodetic(*mean))  # type: ignore[assignment]
            averaged = float(len(self._avg))
            self._avg = []
            n, e, d = pymap3d.ecef2ned(*mean, *self.origin)
            vn = ve = math.nan                 # the origin fix carries position only
        else:
            n, e, d = self._ned(pymap3d, lat, lon, h)
        return Message(message.t, message.sensor, (float(n), float(e), float(d), vn, ve, hdop, vdop, sats,
                                                   float(quality), averaged), message.line)

    def _moving_start(self, pymap3d, message: Message, fix: tuple[float, float, float], speed: float,
                      rest: tuple) -> Message:
        """The origin when the first moving fix (speed m/s) comes before the window's end: the mean of the
        static fixes before it, else this fix; the fix itself is emitted with its velocity (module doc)."""
        p: NmeaParams = self.params  # type: ignore[assignment]
        t = float(message.t)
        if self._avg:
            mean = np.mean(self._avg, axis=0)
            self.origin = tuple(float(v) for v in pymap3d.ecef2geodetic(*mean))  # type: ignore[assignment]
            self.origin_source = (f"mean of the {len(self._avg)} static fixes before the first moving one, at "
                                  f"{t:.3f} s ({speed:.2f} m/s)")
            why = (f"the GPS stream's static start ended at {t:.3f} s ({speed:.2f} m/s > static_speed "
                   f"{p.static_speed:g}), before its origin_s {p.origin_s:g} s: the origin is the mean of the "
                   f"{len(self._avg)} static fixes, the filter starts from the moving fix and its velocity")
            self._avg = []
            n, e, d = self._ned(pymap3d, *fix)
        else:
            self.origin = fix
            self.origin_source = f"the first valid fix, at {t:.3f} s, moving at {speed:.2f} m/s (no static fix)"
            why = (f"no static GPS fix: the first valid fix, at {t:.3f} s, moves at {speed:.2f} m/s (> static_speed "
                   f"{p.static_speed:g}); it is the origin and the filter starts from it and its velocity, "
                   "not from a fix of the static start")
            n = e = d = 0.0
        self.counters["moving_start"] = 1          # only then in info(): a static start's summary is unchanged
        self.events.append(Event(t, "warning", message.sensor, f"nmea: {why}"))
        return Message(message.t, message.sensor, (float(n), float(e), float(d), *rest, 1.0), message.line)
