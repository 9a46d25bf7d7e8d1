"""A live top view of the horizontal track (NED: east right, north up), drawn with braille dots.

Shows the estimated track, the truth when the stream carries truth lines, the beacons and the current
position; scales are equal on both axes and fit everything shown. ``reset()`` (key r) forgets the trail
drawn so far and refits the view to what comes next.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np
from rich.text import Text
from textual.widget import Widget

from fusion.tui.canvas import BrailleCanvas
from fusion.tui.feed import FeedSnapshot

EST, TRUTH, BEACON, NOW = "bold cyan", "#a0a0a0", "bold red", "bold yellow"


class TrackPlot(Widget):
    """Horizontal track of a snapshot: (north, east) points in m."""

    DEFAULT_CSS = """
    TrackPlot { width: 1fr; height: 1fr; min-height: 8; border: round $primary-darken-2; }
    """

    def __init__(self, beacons: Mapping[str, np.ndarray] | None = None, has_position: bool = True, **kwargs) -> None:
        super().__init__(**kwargs)
        self.beacons = {k: np.asarray(v, dtype=float).reshape(-1)[:2] for k, v in (beacons or {}).items()
                        if np.asarray(v).size >= 2}
        self.has_position = has_position
        self.track: np.ndarray = np.zeros((0, 2))
        self.truth: np.ndarray = np.zeros((0, 2))
        self.current: tuple[float, float] | None = None
        self._hide_track = self._hide_truth = 0
        self._totals = (0, 0)
        self.border_title = "track (top view)"
        self.border_subtitle = (f"[{EST}]━ estimate[/] [{TRUTH}]━ truth[/] [{BEACON}]▲ beacon[/] "
                                f"[{NOW}]● now[/]")

    def show(self, snap: FeedSnapshot, current: tuple[float, float] | None) -> None:
        """Take the snapshot's track (only points after the last reset) and the current position."""
        self._totals = (snap.track_total, snap.truth_total)
        self.track = _tail(snap.track, snap.track_total - self._hide_track)
        self.truth = _tail(snap.truth, snap.truth_total - self._hide_truth)
        self.current = current
        self.refresh()

    def reset(self) -> None:
        """Forget the trail so far (the view refits to the points that follow)."""
        self._hide_track, self._hide_truth = self._totals
        self.track = np.zeros((0, 2))
        self.truth = np.zeros((0, 2))
        self.refresh()

    @property
    def points_shown(self) -> int:
        return len(self.track)

    def render(self) -> Text:
        cols, rows = self.content_size.width, self.content_size.height
        if not self.has_position:
            return Text("no horizontal position (block p with 2+ elements) in the state", style="dim")
        if cols < 4 or rows < 2:
            return Text("")
        return self.draw(cols, rows)

    def draw(self, cols: int, rows: int) -> Text:
        """The plot as rich Text of ``cols`` x ``rows`` cells (one row used for the scale)."""
        canvas = BrailleCanvas(cols, rows - 1)
        pts = [self.track, self.truth, np.array(list(self.beacons.values())).reshape(-1, 2)]
        if self.current is not None:
            pts.append(np.array([self.current]))
        allp = np.vstack(pts)
        if not allp.size:
            return Text("waiting for a position estimate", style="dim")
        lo, hi = allp.min(axis=0), allp.max(axis=0)  # (north, east)
        span = np.maximum(hi - lo, 1.0)
        lo, hi = lo - 0.05 * span, hi + 0.05 * span
        w, h = canvas.width - 1, canvas.height - 1
        scale = min(w / (hi[1] - lo[1]), h / (hi[0] - lo[0]))  # dots per metre, equal on both axes
        off_x = (w - scale * (hi[1] - lo[1])) / 2.0
        off_y = (h - scale * (hi[0] - lo[0])) / 2.0

        def to_dots(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            p = np.asarray(p, dtype=float).reshape(-1, 2)
            return off_x + (p[:, 1] - lo[1]) * scale, off_y + (hi[0] - p[:, 0]) * scale

        if len(self.truth):
            canvas.polyline(*to_dots(self.truth), style=TRUTH)
        if len(self.track):
            canvas.polyline(*to_dots(self.track), style=EST)
        for name, b in self.beacons.items():
            x, y = to_dots(b)
            canvas.text(x[0], y[0], "▲" + name, style=BEACON)
        if self.current is not None:
            x, y = to_dots(np.array(self.current))
            canvas.text(x[0], y[0], "●", style=NOW)
        out = canvas.render()
        out.append("\n")
        out.append(_scale_bar(scale, cols), style="dim")
        return out


def _tail(points: tuple[tuple[float, float], ...], n: int) -> np.ndarray:
    n = max(0, min(n, len(points)))
    return np.array(points[len(points) - n:], dtype=float).reshape(-1, 2)


def _scale_bar(dots_per_m: float, cols: int) -> str:
    """``├────┤ 5 m  (east →, north ↑)``: a round length about a quarter of the width."""
    target = cols * 2 / 4 / dots_per_m  # metres in a quarter of the width
    exp = 10.0 ** math.floor(math.log10(target))
    length = max(m * exp for m in (1, 2, 5) if m * exp <= target)
    cells = max(1, int(round(length * dots_per_m / 2)))
    label = f"{length:g} m"
    return ("├" + "─" * max(0, cells - 2) + "┤" if cells >= 2 else "│") + f" {label}  (east →, north ↑)"
