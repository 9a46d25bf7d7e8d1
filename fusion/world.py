"""What a recording declares about its world: the magnetic field, receiver array, beacons, gravity, geodetic
origin and start date of its header (``# mag earth_field_ned: N E D``, ``# receiver 3: x y z``, ``# beacon
B1: x y z``, ``# gravity: g``, ``# origin: lat lon h``, ``# start_utc: ISO``, as ``fusion simulate`` writes
them), each with the file:line it came from; when the header has no origin or date, the first valid NMEA
RMC fix of the log gives them (its GGA the height).

Components read it at wiring from ``BuildContext.extra["world"]`` (:func:`of_context`);
``fusion.header_checks`` compares it with what the config says.
"""
from __future__ import annotations

import datetime as _dt
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, Iterable, TypeVar

import numpy as np

T = TypeVar("T")

#: lines of the log scanned for a first NMEA fix when the header names no origin or date
SCAN_LINES = 20_000


@dataclass(frozen=True)
class Declared(Generic[T]):
    """A value and where it was declared (``path:line``)."""

    value: T
    where: str


@dataclass
class RecordingWorld:
    """The world a recording declares (every entry optional). ``mag_field``: sensor -> NED field in the
    sensor's units; ``mag_units``: sensor -> unit name; ``receivers``: (k, 3) unit normals, receiver r at row
    r - 1; ``origin``: (lat deg, lon deg, height m); ``date``: the UTC start (or the first fix's date)."""

    path: str
    mag_field: dict[str, Declared[np.ndarray]] = field(default_factory=dict)
    mag_units: dict[str, str] = field(default_factory=dict)
    receivers: Declared[np.ndarray] | None = None
    beacons: dict[str, Declared[np.ndarray]] = field(default_factory=dict)
    gravity: Declared[float] | None = None
    origin: Declared[tuple[float, float, float]] | None = None
    date: Declared[_dt.datetime] | None = None
    origin_declared: bool = False     # the origin is the header's '# origin' (not the first NMEA fix)
    streamed: bool = False            # a stream (stdin, a serial port): its header is not known ahead
    problems: list[str] = field(default_factory=list)


_SENSOR_KEY = re.compile(r"^([A-Za-z_][A-Za-z0-9_.\-]*)\s+([A-Za-z_][A-Za-z0-9_]*)\s*:\s*(.*)$")
_KEY = re.compile(r"^([A-Za-z_][A-Za-z0-9_\-]*)\s*:\s*(.*)$")
_RECEIVER = re.compile(r"^receiver\s+(\d+)\s*:\s*(.*)$")


def _floats(text: str, n: int) -> tuple[float, ...] | None:
    try:
        vals = tuple(float(v) for v in text.split())
    except ValueError:
        return None
    return vals if len(vals) == n and all(np.isfinite(vals)) else None


def read_world(path: str | Path) -> RecordingWorld | None:
    """The world declared by the recording at ``path``, or None when it is not a readable text file (a
    device, a pipe, '-', a missing file: the run reports those)."""
    p = Path(path)
    try:
        if str(path) == "-" or not p.is_file():
            return None
        fh = open(p, encoding="utf-8", errors="replace")
    except OSError:
        return None
    try:
        with fh:
            return read_world_lines(fh, str(path))
    except (OSError, ValueError):      # unreadable (an I/O error, a binary file): the run's source reports it
        return None


def read_world_lines(lines: Iterable[str], label: str) -> RecordingWorld:
    """The world declared by a recording's ``lines`` (its header, and its first NMEA fix when the header
    names no origin or date); ``label`` names it in ``where`` (``label:line``)."""
    world = RecordingWorld(label)
    receivers: dict[int, tuple[tuple[float, ...], int]] = {}
    it = iter(lines)
    n = 0
    for n, raw in enumerate(it, 1):
        text = raw.strip().lstrip("\ufeff")
        if not text:
            continue
        if not text.startswith("#"):
            break
        _comment(world, text[1:].strip(), f"{label}:{n}", receivers)
    if world.origin is None or world.date is None:
        _scan_nmea(world, it, n)
    if receivers:
        _set_receivers(world, receivers)
    return world


def _comment(world: RecordingWorld, body: str, where: str, receivers: dict) -> None:
    r = _RECEIVER.match(body)
    if r:
        v = _floats(r.group(2), 3)
        if v is None or not np.linalg.norm(v) > 0:
            world.problems.append(f"{where}: receiver {r.group(1)}: expected 3 numbers, not all zero")
        else:
            receivers[int(r.group(1))] = (v, int(where.rsplit(":", 1)[1]))
        return
    if body.startswith("beacon "):
        name, _, rest = body[7:].partition(":")
        v = tuple(float(x) for x in rest.split()) if rest.strip() else ()
        world.beacons[name.strip()] = Declared(np.asarray(v, float), where)
        return
    m = _SENSOR_KEY.match(body)
    if m and m.group(2) in ("earth_field_ned", "units"):
        if m.group(2) == "units":
            world.mag_units[m.group(1)] = m.group(3).strip()
        else:
            v = _floats(m.group(3), 3)
            if v is None:
                world.problems.append(f"{where}: {m.group(1)} earth_field_ned: expected 3 numbers (N E D)")
            else:
                world.mag_field[m.group(1)] = Declared(np.asarray(v, float), where)
        return
    k = _KEY.match(body)
    if not k:
        return
    key, value = k.group(1), k.group(2).strip()
    if key == "gravity":
        v = _floats(value, 1)
        if v is not None:
            world.gravity = Declared(v[0], where)
    elif key == "origin":
        v = _floats(value, 3) or _floats(value, 2)
        if v is not None:
            world.origin = Declared((v[0], v[1], v[2] if len(v) > 2 else 0.0), where)
            world.origin_declared = True
    elif key == "start_utc":
        try:
            world.date = Declared(_dt.datetime.fromisoformat(value.replace("Z", "+00:00")), where)
        except ValueError:
            world.problems.append(f"{where}: start_utc: not an ISO date-time: {value!r}")


def _set_receivers(world: RecordingWorld, receivers: dict[int, tuple[tuple[float, ...], int]]) -> None:
    numbers = sorted(receivers)
    first = min(line for _, line in receivers.values())
    where = f"{world.path}:{first}"
    if numbers != list(range(1, len(numbers) + 1)):
        world.problems.append(f"{where}: the '# receiver N' lines must number the receivers 1..k without a gap; "
                              f"got {numbers}")
        return
    normals = np.array([receivers[i][0] for i in numbers], float)
    world.receivers = Declared(normals / np.linalg.norm(normals, axis=1, keepdims=True), where)


def _scan_nmea(world: RecordingWorld, fh: Any, start: int) -> None:
    """Origin and date from the first valid RMC fix (height from the first GGA) in the next lines."""
    import pynmea2

    height = None
    for n, raw in enumerate(fh, start + 1):
        if n > SCAN_LINES:
            return
        i = raw.find(",$")
        if i < 0:
            continue
        try:
            msg = pynmea2.parse(raw[i + 1:].strip())
        except (pynmea2.ParseError, ValueError, AttributeError):
            continue
        where = f"{world.path}:{n} (the first NMEA fix)"
        kind = getattr(msg, "sentence_type", "")
        if kind == "GGA" and height is None and getattr(msg, "altitude", None) not in (None, ""):
            height = float(msg.altitude) + float(msg.geo_sep or 0.0)
        if kind == "RMC" and getattr(msg, "status", "") == "A" and msg.datestamp is not None:
            if world.origin is None:
                world.origin = Declared((float(msg.latitude), float(msg.longitude), height or 0.0), where)
            if world.date is None:
                world.date = Declared(_dt.datetime.combine(msg.datestamp, msg.timestamp or _dt.time()), where)
            return


def of_context(context: Any) -> RecordingWorld | None:
    """The recording's world a component was wired with (``BuildContext.extra["world"]``), or None."""
    extra = getattr(context, "extra", None) or {}
    world = extra.get("world")
    return None if world is None or world.streamed else world
