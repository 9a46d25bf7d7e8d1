"""The status line: source, state (RECONNECTING with the attempt count), overall health (OK, DEGRADED,
LOST) with its reason, sensor time, speed against real time, filter, lines read, and for a live port that
the view cannot keep up with, how far behind it is (``BEHIND by 12.3 s``). In a narrow terminal the parts
of least use are left out so that it stays one line; what is wrong still wraps onto a second line rather
than being cut."""
from __future__ import annotations

import os
import time

from rich.text import Text
from textual.widgets import Static

from fusion.tui.snapshot import FeedSnapshot
from fusion.tui.health_panel import STATE_STYLE

SILENT_S = 5.0  # s without a byte on a live port: LOST (as fusion.tui.health)
BEHIND_S = 1.0  # s a live view may lag its device before the status line says BEHIND by N s

_STATE_STYLE = {"running": "bold green", "waiting": "bold", "finished": "bold blue", "paused": "bold yellow",
                "lost": "bold red", "error": "bold red", "stopped": "bold", "reconnecting": "bold yellow"}


#: What a narrow status line leaves out, in turn, until it fits its width: the filter (the header names it),
#: the source's folder, the speed against real time, the lines read.
_COMPACT = ({}, {"filter": False}, {"filter": False, "folder": False},
            {"filter": False, "folder": False, "speed": False},
            {"filter": False, "folder": False, "speed": False, "lines": False})


def describe(snap: FeedSnapshot, paused: bool, filter_name: str, now: float | None = None,
             width: int | None = None) -> Text:
    """One line: ``replay recordings/x.log | running | t = 12.345 s | 4.0x real time | filter ukf | 1234 lines``.
    With ``width`` (cells), the parts of least use are left out (``_COMPACT``) until it fits: only the
    state, health, time and what is wrong (BEHIND, a message) remain, and a line still longer wraps."""
    for leave_out in _COMPACT:
        out = _describe(snap, paused, filter_name, now, **leave_out)
        if width is None or out.cell_len <= width:
            break
    return out


def _describe(snap: FeedSnapshot, paused: bool, filter_name: str, now: float | None, filter: bool = True,
              folder: bool = True, speed: bool = True, lines: bool = True) -> Text:
    state = "paused" if paused and snap.state in ("running", "waiting") else snap.state
    out = Text()
    source = snap.source if folder or "://" in snap.source else os.path.basename(snap.source)
    out.append(f" {'live' if snap.live else 'replay'} {source} ")
    label = f"RECONNECTING (attempt {snap.attempt})" if state == "reconnecting" else state.upper()
    out.append(f" {label} ", style="reverse " + _STATE_STYLE.get(state, "bold"))
    health = snap.health
    listening = snap.live and snap.state in ("running", "waiting") and now is not None
    silent = now - snap.data_wall if listening else 0.0   # since the last byte, or since opening: none yet
    if health is not None:
        overall, reason = health.state, health.reason
        if silent > SILENT_S and overall != "LOST":  # the feed posts nothing while the port is silent
            overall, reason = "LOST", f"no data for {silent:.0f} s"
        out.append(" ")
        out.append(f" {overall} ", style="reverse " + STATE_STYLE.get(overall, "bold"))
        if reason != snap.message and overall != "OK":
            out.append(f" {reason}")
    parts = [f"t = {snap.sensor_t:.3f} s" if snap.sensor_t == snap.sensor_t else "t = -"]
    if speed and snap.speed_ratio == snap.speed_ratio and not paused:
        parts.append(f"{snap.speed_ratio:.1f}x real time")
    parts += [f"filter {filter_name}"] if filter else []
    parts += [f"{snap.lines} lines"] if lines else []
    if listening and now - snap.data_wall > 2.0:
        parts.append(f"no data for {now - snap.data_wall:.0f} s")
    out.append(" | " + " | ".join(parts))
    if snap.live and snap.lag_s >= BEHIND_S and snap.state == "running":   # NaN: not compared
        out.append(" | ")
        out.append(f"BEHIND by {snap.lag_s:.1f} s", style="bold yellow")
    if snap.message:
        out.append(" | ")
        out.append(snap.message, style="bold red")
    return out


class StatusLine(Static):
    """Shows ``describe()`` of the latest snapshot; ``text`` is its plain text."""

    DEFAULT_CSS = """
    StatusLine { height: auto; max-height: 3; background: $panel; }
    """

    def __init__(self, filter_name: str, **kwargs) -> None:
        super().__init__("", **kwargs)
        self.filter_name = filter_name
        self.text = ""
        self._snap: FeedSnapshot | None = None
        self._paused = False

    def show(self, snap: FeedSnapshot, paused: bool) -> None:
        self._snap, self._paused = snap, paused
        self.tick()

    def tick(self) -> None:
        """Re-render (also called by a timer so 'no data for N s' counts up on a silent port)."""
        if self._snap is None:
            return
        width = self.size.width or self.app.size.width
        line = describe(self._snap, self._paused, self.filter_name, time.monotonic(), width=width)
        self.text = line.plain
        self.update(line)
