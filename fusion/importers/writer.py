"""Write an ImportedLog in the fusion log format: header, ``# fields`` lines, messages in time order.

Outputs are written to a temporary name in the same folder and renamed (never half a file under the final
name); an existing file is replaced only with ``force``, the input never; a FIFO, a device or ``-``
(stdout) is streamed to as it is.
"""
from __future__ import annotations

import heapq
import os
import stat
import sys
from pathlib import Path
from typing import IO, Iterator

import numpy as np

from fusion.api import ConfigError, ImportedLog, InputError, Stream
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


def render(log: ImportedLog) -> Iterator[str]:
    """Lines (with newline) of the whole recording: header, then every stream merged by time (stable: at
    equal times, streams keep their order), formatted a chunk at a time (memory bounded by the streams)."""
    for s in log.streams:
        if not _SENSOR.match(s.sensor):
            raise ConfigError(f"sensor name {s.sensor!r} is not valid in the log format (letters, digits, _ . -)")
    yield "# fusion-log 1\n"
    for k, v in log.meta.items():
        yield f"# {k}: {v}\n"
    for t, text in log.messages[:MAX_MESSAGES]:
        yield f"# message {t:.3f}: {' '.join(str(text).split())}\n"
    if len(log.messages) > MAX_MESSAGES:
        yield f"# message: ... and {len(log.messages) - MAX_MESSAGES} more\n"
    for s in log.streams:
        for k, v in s.meta.items():
            yield f"# {s.sensor} {k}: {v}\n"
    for s in log.streams:
        yield f"# fields {s.sensor} " + " ".join(s.fields) + (" ..." if s.repeat else "") + "\n"
    for _, _, line in heapq.merge(*[_keyed(s, k) for k, s in enumerate(log.streams)]):
        yield line + "\n"


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return a.resolve() == b.resolve()


def check_output(output: str, inputs: list[str], force: bool = False) -> str:
    """How ``output`` will be written: ``stdout``, ``stream`` (an existing FIFO or device) or ``file``
    (through a temporary name). InputError for an input, an existing file without ``force``, a folder, or a
    missing parent folder (checked before a long import, and again before writing)."""
    if output == "-":
        return "stdout"
    out = Path(output)
    if out.exists():
        for src in inputs:
            if _same_file(out, Path(src)):
                raise InputError(f"{out}: is an input of this import; choose another output")
        mode = out.stat().st_mode
        if stat.S_ISFIFO(mode) or stat.S_ISCHR(mode):
            return "stream"
        if out.is_dir():
            raise InputError(f"{out}: is a folder")
        if not force:
            raise InputError(f"{out}: exists; pass --force to replace it")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"{out}: folder {parent} does not exist")
    return "file"


def write_log(log: ImportedLog, output: str, inputs: list[str], force: bool = False) -> tuple[int, int]:
    """Write ``log`` to ``output`` (``-``: stdout). Returns (message lines, bytes). Refuses (InputError) to
    write over any of ``inputs``, or over an existing regular file without ``force``."""
    how = check_output(output, inputs, force)
    if how == "stdout":
        return _write_to(sys.stdout, log)
    out = Path(output)
    if how == "stream":
        with open(out, "w", encoding="utf-8", newline="\n") as fh:
            return _write_to(fh, log)
    tmp = out.with_name(f".{out.name}.tmp{os.getpid()}")
    try:
        with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
            counts = _write_to(fh, log)
        os.replace(tmp, out)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise InputError(f"{out}: cannot write: {exc.strerror or exc}") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return counts


def _write_to(fh: IO[str], log: ImportedLog) -> tuple[int, int]:
    n = size = 0
    for line in render(log):
        fh.write(line)
        size += len(line)
        if line[0] != "#":
            n += 1
    fh.flush()
    return n, size
