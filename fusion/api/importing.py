"""The importer kind (``fusion import``): what is asked for, what comes back."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from .components import Component

__all__ = ["ImportRequest", "Stream", "ImportedLog", "Importer"]


@dataclass(frozen=True)
class ImportRequest:
    """What ``fusion import`` asks an importer for: the time span ``start``..``end`` (s, on the output's time
    axis, i.e. from the log's own time zero; None: unbounded), the sensor names wanted (None: all the format
    has), the mapping file (CSV), and whether a truncated or corrupt file may be imported as far as it reads
    (``allow_partial``; otherwise it is an InputError). Importers read only what is asked for where the
    format allows it (topics, message types, columns) and cut the span themselves."""

    start: float | None = None
    end: float | None = None
    sensors: frozenset[str] | None = None
    mapping: str | None = None
    allow_partial: bool = False

    def wants(self, sensor: str) -> bool:
        """True when ``sensor`` (``imu2``), or its family (``imu``: every instance), was asked for."""
        if self.sensors is None:
            return True
        return sensor in self.sensors or sensor.rstrip("0123456789") in self.sensors

    def wants_family(self, family: str) -> bool:
        """True when any sensor of ``family`` (``imu``, ``imu2``, ...) was asked for: its data must be read."""
        if self.sensors is None:
            return True
        return any(s.rstrip("0123456789") == family for s in self.sensors)


@dataclass
class Stream:
    """One sensor's samples: times ``t`` (k,) in s and ``values`` (k, m), columns named by ``fields``
    (written as ``# fields SENSOR ...``). ``formats``: a format spec a column (``".7f"``), default
    ``".9g"`` (round-trips float32); a column of ``dtype=object`` holds labels (beacon names). ``meta``:
    ``# SENSOR key: value`` header lines (units, source topic). ``repeat``: the fields form a group that
    repeats on a line (``beacon range ...``); ``rows`` then holds ready value tuples instead of ``values``."""

    sensor: str
    fields: tuple[str, ...]
    t: np.ndarray
    values: np.ndarray | None = None
    formats: tuple[str, ...] | None = None
    meta: dict[str, str] = field(default_factory=dict)
    repeat: bool = False
    rows: list[tuple[Any, ...]] | None = None

    def __len__(self) -> int:
        return int(len(self.t))


@dataclass
class ImportedLog:
    """What an importer returns: header metadata (``# key: value``, in order), the streams, notes for the
    user (printed by the command, e.g. "gps: 3 samples without a fix dropped"), every file it read besides
    the one it was given (``inputs``: never overwritten by the output), and the log's own text messages
    (``messages``: "Takeoff detected" at t; written as ``# message T: text`` header comments)."""

    meta: dict[str, str] = field(default_factory=dict)
    streams: list[Stream] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    inputs: list[str] = field(default_factory=list)
    messages: list[tuple[float, str]] = field(default_factory=list)  # the log's text messages (t s, text)


class Importer(Component):
    """Reads a log of another format (PX4 ULog, ArduPilot DataFlash, CSV by a mapping) into streams that
    ``fusion import`` writes in the fusion log format. ``suffixes``: the file name endings it reads
    (``(".ulg",)``), used to choose it; ``sensors``: the sensor families it can produce (``imu``, ``gps``,
    ``mag``, ``baro``, ``reference``, ...). Units out are SI and frames NED/FRD (DESIGN.md), except GPS
    latitude/longitude in degrees and altitude in metres above mean sea level, and magnetic field in uT."""

    kind: ClassVar[str] = "importer"
    suffixes: ClassVar[tuple[str, ...]] = ()
    sensors: ClassVar[tuple[str, ...]] = ()

    def read(self, path: str, request: ImportRequest) -> ImportedLog:
        """Read ``path``; raise InputError (what and where) for a file that is not of this format or is
        damaged, ConfigError for a bad mapping or request."""
        raise NotImplementedError
