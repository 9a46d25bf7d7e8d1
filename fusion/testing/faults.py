"""Faults for tests: a full disk without root (what a sink or an output does when a write fails), and a
recording with lines cut out (a pause, a dropout: :func:`cut_recording`).

``full_disk_after(monkeypatch, nbytes)`` makes every temporary file that :class:`fusion.outputs.OutputFile`
writes (every built-in output, and a plugin's sink that writes through it) fail with ``ENOSPC`` once
``nbytes`` have been written to it, as a real full file system would::

    from fusion.testing.faults import full_disk_after

    def test_my_sink_on_a_full_disk(tmp_path, monkeypatch):
        full_disk_after(monkeypatch, 100)
        assert main(["run", "my.yaml", "-q", "-o", str(tmp_path / "out.tsv")]) == 2
        assert not (tmp_path / "out.tsv").exists()

:class:`FullAfter` is the file wrapper itself, for a file opened some other way.
"""
from __future__ import annotations

import errno
import math
import os
from typing import Any

__all__ = ["FullAfter", "full_disk_after", "cut_recording", "thin_truth"]


class FullAfter:
    """A text or binary file object whose writes raise ``OSError(ENOSPC)`` once ``nbytes`` characters (or
    bytes) have been written in all; everything else is the wrapped file's."""

    def __init__(self, f: Any, nbytes: int):
        self._f, self._left = f, int(nbytes)

    def write(self, data: Any) -> int:
        self._left -= len(data)
        if self._left < 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return self._f.write(data)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._f, name)

    def __enter__(self) -> "FullAfter":
        return self

    def __exit__(self, *exc: Any) -> None:
        self._f.close()

    def __iter__(self):
        return iter(self._f)


def full_disk_after(monkeypatch: Any, nbytes: int) -> None:
    """With pytest's ``monkeypatch``: the temporary files ``fusion.outputs`` opens for writing become
    :class:`FullAfter` ``nbytes``."""
    import fusion.outputs as outputs

    real_fdopen = os.fdopen

    def fdopen(fd: int, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
        f = real_fdopen(fd, mode, *args, **kwargs)
        return FullAfter(f, nbytes) if mode.startswith("w") else f

    monkeypatch.setattr(outputs.os, "fdopen", fdopen)


def cut_recording(source: Any, drop: Any = None, end: float | None = None) -> list[str]:
    """The lines of a recording (a path, or its lines) up to ``end`` s, without the data lines for which
    ``drop(t, line)`` is true (a pause of every stream, one sensor's dropout, an outage); header and comment
    lines are kept. What a pipeline run or ``fusion run --input`` takes::

        paused = cut_recording("recordings/car_gps_mag.log", lambda t, ln: 80.0 <= t < 85.0, end=120.0)
    """
    lines = source if not isinstance(source, (str, os.PathLike)) else open(source, encoding="utf-8").read().splitlines()
    out = []
    for ln in lines:
        if ln.startswith("#"):
            out.append(ln)
            continue
        t = float(ln.split(",", 1)[0])
        if end is not None and t > end:
            break
        if drop is None or not drop(t, ln):
            out.append(ln)
    return out


def thin_truth(source: Any, min_interval: float) -> list[str]:
    """The lines of a recording (a path, or its lines) with its truth lines thinned to at most one per
    ``min_interval`` s (the first kept, then each at least that long after the last kept); every other line
    kept. Truth coarser than the estimates, e.g. ``thin_truth("recordings/uwb_route1.log", 0.999)`` for 1 Hz."""
    state = {"last": -math.inf}

    def drop(t: float, line: str) -> bool:
        if ",truth," not in line:
            return False
        if t - state["last"] < min_interval:
            return True
        state["last"] = t
        return False

    return cut_recording(source, drop)

