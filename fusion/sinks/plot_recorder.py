"""What ``--plot`` draws, kept in bounded memory while a run streams (fusion.pipeline feeds it).

``PlotRecorder`` keeps at most about ``max_points`` estimates (time, state, sd and the truth at that time)
and as many NIS samples per sensor, whatever the length of the run. Decimation keeps extremes: the
stream is cut into buckets of ``stride`` consecutive samples, each bucket keeps its sample of largest
score (the position error when truth is there, the NIS for NIS samples; without a score, the first), and
when the buckets fill, neighbours merge and the stride doubles. The largest error and the largest NIS
of a run are therefore always in the plot; the last sample too.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["PlotRecorder", "ExtremeDecimator"]


class ExtremeDecimator:
    """At most ``max_points`` items of a stream (about ``max_points / 2`` after a merge), each the
    highest-score item of its bucket, in stream order, plus the last item."""

    def __init__(self, max_points: int = 5000):
        self.max_points = max(4, int(max_points))
        self.stride = 1
        self._kept: list[tuple[float, Any]] = []  # (score, item), one per closed bucket
        self._open: tuple[float, Any] | None = None
        self._in_open = 0
        self._last: Any = None
        self.count = 0

    def add(self, item: Any, score: float = 0.0) -> None:
        self.count += 1
        self._last = item
        score = score if score == score else math.inf  # a NaN (diverged) is an extreme worth seeing
        if self._open is None or score > self._open[0]:
            self._open = (score, item)
        self._in_open += 1
        if self._in_open >= self.stride:
            self._kept.append(self._open)
            self._open, self._in_open = None, 0
            if len(self._kept) >= self.max_points:
                self._merge()

    def _merge(self) -> None:
        k = self._kept
        self._kept = [max(k[i], k[i + 1], key=lambda p: p[0]) if i + 1 < len(k) else k[i]
                      for i in range(0, len(k), 2)]
        self.stride *= 2

    def items(self) -> list[Any]:
        out = [item for _, item in self._kept]
        if self._open is not None:
            out.append(self._open[1])
        if self._last is not None and (not out or out[-1] is not self._last):
            out.append(self._last)
        return out


class PlotRecorder:
    """Collects a run's plot data: ``on_result(estimate, errors, truth_row)`` for each estimate (errors
    and row None without truth), ``on_nis(sensor, t, nis, dim)`` for each update; ``write(path, system)``
    draws it with ``fusion.sinks.plot.plot_run``."""

    def __init__(self, max_points: int = 5000):
        self.max_points = max_points
        self._est = ExtremeDecimator(max_points)
        self._nis: dict[str, ExtremeDecimator] = {}
        self._dim: dict[str, int] = {}
        self.truth_names: tuple[str, ...] | None = None

    def on_result(self, estimate, errors: dict | None, row: np.ndarray | None) -> None:
        b = estimate.belief
        score = errors.get("position_m", 0.0) if errors else 0.0
        self._est.add((float(estimate.t), np.array(b.x, dtype=float), b.sd, row), score)

    def on_nis(self, sensor: str, t: float, nis: float, dim: int) -> None:
        dec = self._nis.get(sensor)
        if dec is None:
            dec = self._nis[sensor] = ExtremeDecimator(self.max_points)
        self._dim[sensor] = int(dim)
        dec.add((float(t), float(nis)), float(nis))

    def write(self, path: str, system, stats=None, title: str = "") -> None:
        """Draw the plot. ``stats``: the run's ``RunStats`` (truth names, NIS fractions over every update)."""
        from fusion.metrics import Truth
        from fusion.sinks.plot import plot_run

        n = system.layout.n
        items = self._est.items()
        t = np.array([i[0] for i in items], dtype=float)
        x = np.array([i[1] for i in items]).reshape(-1, n) if items else np.zeros((0, n))
        sd = np.array([i[2] for i in items]).reshape(-1, n) if items else np.zeros((0, n))
        names = None
        if stats is not None and stats.truth is not None:
            names = stats.truth.window.names
        truth = rows = None
        have = [i for i in items if i[3] is not None]
        if names and have:
            truth = Truth(np.array([i[0] for i in have]), np.array([i[3] for i in have]), names)
            rows = np.array([i[3] if i[3] is not None else np.full(len(names), np.nan) for i in items])
        fractions = {}
        if stats is not None:
            fractions = {s: st.in_fraction for s, st in stats.tracker.nis.stats.items() if st.count}
        nis = {}
        for sensor, dec in self._nis.items():
            pts = dec.items()
            nis[sensor] = (np.array([p[0] for p in pts]), np.array([p[1] for p in pts]), self._dim[sensor],
                           fractions.get(sensor))
        plot_run(path, system.layout, t, x, sd, truth, system.beacons, nis, title=title, truth_rows=rows)
