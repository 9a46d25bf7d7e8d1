"""Write an ImportedLog in the fusion log format: header, ``# fields`` lines, messages in time order.

Written through fusion.outputs like every command's outputs: a temporary name in the same folder renamed
when complete (never half a file under the final name); an existing file is replaced only with ``force``,
an input never; a FIFO, a device or ``-`` (stdout) is streamed to as it is.
"""
from __future__ import annotations

import heapq
from typing import Iterator

import numpy as np

from fusion.api import ConfigError, ImportedLog, Stream
from fusion.importers.common import F32
from fusion.logformat import _SENSOR


def _column_text(col: np.ndarray, spec: str) -> list[str]:
    if col.dtype == object:
        return [v if isinstance(v, str) else format(float(v), spec) for v in col.tolist()]
    if spec == "d":
        return [str(int(v)) for v in col.tolist()]
    return [format(v, spec) for v in col.tolist()]


_CHUNK = 20000
MAX_MESSAGES = 200   # the log's text messages written to the header (flight events: takeoff, landing, modes)
EVENT_WORDS = ("ARMED", "DISARMED", "MODE", "FAILSAFE", "EVENT", "ERROR")   # fusion.importers.flight_events


def stream_lines(s: Stream, start: int = 0, stop: int | None = None) -> list[str]:
    """The message lines of rows ``start:stop`` of one stream (no newline), ``t`` with microsecond resolution."""
    ts = [f"{t:.6f}" for t in np.asarray(s.t[start:stop], float).tolist()]
    if s.rows is not None:
        return [f"{t},{s.sensor}," + ",".join(v if isinstance(v, str) else format(float(v), F32) for v in row)
                for t, row in zip(ts, s.rows[start:stop])]
    vals = np.asarray(s.values[start:stop])
    specs = s.formats or (F32,) * vals.shape[1]
    cols = [_column_text(vals[:, j], specs[j]) for j in range(vals.shape[1])]
    prefix = f",{s.sensor},"
    return [t + prefix + ",".join(parts) for t, parts in zip(ts, zip(*cols))]


def _keyed(s: Stream, k: int) -> Iterator[tuple[float, int, str]]:
    """(time as written, stream index, line) of a stream, formatted a chunk at a time."""
    t = np.round(np.asarray(s.t, float), 6)   # sorted on the times as written: 0.1499999 and 0.15 are equal
    order = np.argsort(t, kind="stable")
    if np.any(np.diff(order) != 1):
        s = Stream(s.sensor, s.fields, s.t[order], None if s.values is None else np.asarray(s.values)[order],
                   s.formats, s.meta, s.repeat, None if s.rows is None else [s.rows[i] for i in order])
        t = t[order]
    for a in range(0, len(t), _CHUNK):
        lines = stream_lines(s, a, a + _CHUNK)
        yield from zip(t[a:a + _CHUNK].tolist(), [k] * len(lines), lines)


def _text(value) -> str:
    """A header value on one printable line: a log's info string may carry NULs or newlines (PX4's sys_name
    'PX4\\0\\0' would make the recording a binary file to grep)."""
    return " ".join("".join(c if c.isprintable() else " " for c in str(value)).split())


def render(log: ImportedLog) -> Iterator[str]:
    """Lines (with newline) of the whole recording: header, then every stream merged by time (stable: at
    equal times, streams keep their order), formatted a chunk at a time (memory bounded by the streams)."""
    for s in log.streams:
        if not _SENSOR.match(s.sensor):
            raise ConfigError(f"sensor name {s.sensor!r} is not valid in the log format (letters, digits, _ . -)")
    yield "# fusion-log 1\n"
    for k, v in log.meta.items():
        yield f"# {k}: {_text(v)}\n"
    texts = 0
    for t, text in log.messages:     # the flight's events all, the log's other texts up to MAX_MESSAGES
        event = str(text).split(" ", 1)[0] in EVENT_WORDS
        texts += not event
        if event or texts <= MAX_MESSAGES:
            yield f"# message {t:.3f}: {' '.join(str(text).split())}\n"
    if texts > MAX_MESSAGES:
        yield f"# message: ... and {texts - MAX_MESSAGES} more\n"
    for s in log.streams:
        for k, v in s.meta.items():
            yield f"# {s.sensor} {k}: {_text(v)}\n"
    for s in log.streams:
        yield f"# fields {s.sensor} " + " ".join(s.fields) + (" ..." if s.repeat else "") + "\n"
    for _, _, line in heapq.merge(*[_keyed(s, k) for k, s in enumerate(log.streams)]):
        yield line + "\n"


def write_log(log: ImportedLog, output: str, inputs: list[str], force: bool = False) -> tuple[int, int]:
    """Write ``log`` to ``output`` (``-``: stdout) through fusion.outputs (the outputs of every command:
    checked against the ``inputs`` and ``force`` first, then a temporary name renamed when complete, a FIFO
    or device written in place). Returns (message lines, characters). A failed write (disk full) leaves
    no partial file and is one FusionError line."""
    from fusion.outputs import OutputFile, check_outputs

    check_outputs({"-o": output}, inputs, force=force)
    out = OutputFile(output, "w", what="recording")
    try:
        counts = _write_to(out, log)
    except BaseException:
        out.discard()
        raise
    out.close()
    return counts


def _write_to(out, log: ImportedLog, chunk: int = 1 << 16) -> tuple[int, int]:
    n = size = 0
    buf: list[str] = []
    held = 0
    for line in render(log):
        buf.append(line)
        held += len(line)
        size += len(line)
        if line[0] != "#":
            n += 1
        if held >= chunk:
            out.write("".join(buf))
            buf, held = [], 0
    if buf:
        out.write("".join(buf))
    return n, size
