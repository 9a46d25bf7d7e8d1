"""A live top view of the horizontal track (NED: east right, north up), drawn with braille dots.

Shows the estimated track, the truth when the stream carries truth lines (and the latest true position
beside the estimate), the beacons, the current position and its 2-sigma covariance ellipse (the
horizontal 2 x 2 block of P: semi-axes 2 sqrt(eigenvalue), 86% of the probability of a Gaussian);
scales are equal on both axes and fit everything shown. With ``fusion tui --smooth-lag L`` the fixed-lag
smoothed track (each point L s behind the live estimate, smoothed on the measurements up to now) is a
second trace. ``zoom`` (keys + and -) narrows the view around
its centre, ``follow`` (key f) centres it on the current estimate; ``reset()`` (key r) forgets the trail
drawn so far and refits the view to what comes next.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np
from rich.text import Text
from textual.widget import Widget

from fusion.tui.canvas import BrailleCanvas
from fusion.tui.snapshot import FeedSnapshot

EST, TRUTH, BEACON, NOW, ELLIPSE = "bold cyan", "#a0a0a0", "bold red", "bold yellow", "yellow"
SMOOTHED = "bold magenta"


def ellipse_points(center: np.ndarray, cov: np.ndarray, k: float = 2.0, n: int = 64) -> np.ndarray:
    """(n, 2) points of the k-sigma ellipse of a 2 x 2 covariance around ``center`` (same units, m)."""
    w, V = np.linalg.eigh(0.5 * (cov + cov.T))
    a = np.linspace(0.0, 2.0 * math.pi, n)
    unit = np.stack([np.cos(a), np.sin(a)], axis=1)
    return np.asarray(center, dtype=float) + (unit * (k * np.sqrt(np.clip(w, 0.0, None)))) @ V.T


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
        self.smoothed: np.ndarray = np.zeros((0, 2))  # the fixed-lag smoothed track (--smooth-lag), m
        self.smooth_lag: float | None = None
        self.current: tuple[float, float] | None = None
        self.cov: np.ndarray | None = None  # (2, 2) horizontal covariance at the current estimate, m^2
        self.truth_now: tuple[float, float] | None = None
        self.zoom = 1.0
        self.follow = False
        self._hide_track = self._hide_truth = self._hide_smoothed = 0
        self._totals = (0, 0, 0)
        self.border_title = "track (top view)"
        self.border_subtitle = self._legend()

    def _legend(self) -> str:
        lag = (f"[{SMOOTHED}]━ smoothed {self.smooth_lag:g} s late[/] " if self.smooth_lag is not None else "")
        return (f"[{EST}]━ estimate[/] {lag}[{TRUTH}]━ truth[/] [{BEACON}]▲ beacon[/] "
                f"[{NOW}]● now[/] [{ELLIPSE}]◌ 2σ[/] [{TRUTH}]○ true now[/]")

    def show(self, snap: FeedSnapshot, current: tuple[float, float] | None, cov: np.ndarray | None = None) -> None:
        """Take the snapshot's track (only points after the last reset), the current position and its
        horizontal covariance (2 x 2, m^2)."""
        self.cov = None if cov is None or not np.isfinite(cov).all() else np.asarray(cov, dtype=float)
        self.truth_now = snap.truth[-1] if snap.truth else None
        self._totals = (snap.track_total, snap.truth_total, snap.smoothed_total)
        self.track = _tail(snap.track, snap.track_total - self._hide_track)
        self.truth = _tail(snap.truth, snap.truth_total - self._hide_truth)
        self.smoothed = _tail(snap.smoothed, snap.smoothed_total - self._hide_smoothed)
        if snap.smooth_lag != self.smooth_lag:
            self.smooth_lag = snap.smooth_lag
            self.border_subtitle = self._legend()
        self.current = current
        self.refresh()

    @property
    def hidden(self) -> tuple[int, int]:
        """The reset marks (points of the track and of truth hidden before them), kept across a relayout."""
        return self._hide_track, self._hide_truth

    @hidden.setter
    def hidden(self, marks: tuple[int, int]) -> None:
        self._hide_track, self._hide_truth = marks

    def reset(self) -> None:
        """Forget the trail so far (the view refits to the points that follow)."""
        self._hide_track, self._hide_truth, self._hide_smoothed = self._totals
        self.track = np.zeros((0, 2))
        self.truth = np.zeros((0, 2))
        self.smoothed = np.zeros((0, 2))
        self.refresh()

    def set_zoom(self, factor: float) -> None:
        """Multiply the zoom (1 = fit everything); kept within 1/4 to 1000."""
        self.zoom = min(1000.0, max(0.25, self.zoom * factor))
        self.refresh()

    def toggle_follow(self) -> None:
        self.follow = not self.follow
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
        pts = [self.track, self.truth, self.smoothed, np.array(list(self.beacons.values())).reshape(-1, 2)]
        ring = None
        if self.current is not None:
            pts.append(np.array([self.current]))
            if self.cov is not None:
                ring = ellipse_points(np.array(self.current), self.cov)
                if not self.follow and self.zoom == 1.0:
                    pts.append(ring)
        allp = np.vstack(pts)
        if not allp.size:
            return Text("waiting for a position estimate", style="dim")
        lo, hi = allp.min(axis=0), allp.max(axis=0)  # (north, east)
        span = np.maximum(hi - lo, 1.0)
        lo, hi = lo - 0.05 * span, hi + 0.05 * span
        if self.zoom != 1.0 or self.follow:
            centre = np.array(self.current) if self.follow and self.current is not None else (lo + hi) / 2.0
            half = (hi - lo) / (2.0 * self.zoom)
            lo, hi = centre - half, centre + half
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
        if len(self.smoothed):
            canvas.polyline(*to_dots(self.smoothed), style=SMOOTHED)
        if ring is not None:
            canvas.polyline(*to_dots(ring), style=ELLIPSE)
        for name, b in self.beacons.items():
            x, y = to_dots(b)
            canvas.text(x[0], y[0], "▲" + name, style=BEACON)
        if self.truth_now is not None:
            x, y = to_dots(np.array(self.truth_now))
            canvas.text(x[0], y[0], "○", style=TRUTH)
        if self.current is not None:
            x, y = to_dots(np.array(self.current))
            canvas.text(x[0], y[0], "●", style=NOW)
        out = canvas.render()
        out.append("\n")
        view = (" follow" if self.follow else "") + (f" zoom {self.zoom:g}x" if self.zoom != 1.0 else "")
        out.append(_scale_bar(scale, cols) + view, style="dim")
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
