"""Time-series panels of one sensor's updates: the test ratio (NIS / gate threshold) with the gate at 1,
and one innovation element with +-sqrt(S) (its 1-sigma band), over the last updates (fusion.tui.series).

Drawn with textual-plotext (Plotext in a Textual widget): it draws several series, a horizontal gate line
and labelled axes, which the view needs; Textual's own Sparkline draws one series of bars scaled to its
own min/max, with no reference line, so it cannot show the gate or the +-sqrt(S) band. Plotext builds
its canvas in Python, so the panels redraw at most
``plot_hz`` times a second and only while visible (a widget in a hidden tab is not rendered).
"""
from __future__ import annotations

import math
import time
from typing import Mapping

from textual.containers import Vertical
from textual_plotext import PlotextPlot

from fusion.tui.series import Sample


class InnovationPanel(Vertical):
    """``sensor``/``element``: what is plotted (chosen with ``next_sensor``/``next_element``, keys s/e)."""

    DEFAULT_CSS = """
    InnovationPanel { height: 1fr; min-height: 10; border: round $primary-darken-2; }
    InnovationPanel PlotextPlot { height: 1fr; }
    """

    def __init__(self, plot_hz: float = 4.0, **kwargs) -> None:
        super().__init__(**kwargs)
        self.border_title = "innovations"
        self.sensor: str | None = None
        self.element = 0
        self.series: Mapping[str, tuple[Sample, ...]] = {}
        self.plot_dt = 1.0 / plot_hz if plot_hz > 0 else 0.0
        self._drawn = -math.inf
        self.draws = 0

    def compose(self):
        yield PlotextPlot(id="ratio")
        yield PlotextPlot(id="innovation")

    def show(self, series: Mapping[str, tuple[Sample, ...]], force: bool = False) -> None:
        self.series = series
        if self.sensor not in series and series:
            self.sensor, self.element = sorted(series)[0], 0
        now = time.monotonic()
        if force or now - self._drawn >= self.plot_dt:
            self._drawn = now
            self.draw()

    def next_sensor(self) -> None:
        names = sorted(self.series)
        if names:
            i = names.index(self.sensor) + 1 if self.sensor in names else 0
            self.sensor, self.element = names[i % len(names)], 0
        self.draw()

    def next_element(self) -> None:
        dim = max((len(s.y) for s in self.series.get(self.sensor or "", ())), default=1)
        self.element = (self.element + 1) % max(dim, 1)
        self.draw()

    def draw(self) -> None:
        """Redraw both plots from the samples of the chosen sensor."""
        self.draws += 1
        samples = self.series.get(self.sensor or "", ())
        k = self.element
        gated = any(s.ratio == s.ratio for s in samples)
        self.border_title = (f"innovations: {self.sensor or '-'}  (s sensor, e element)" if self.sensor
                             else "innovations: no updates yet")
        ratio, inn = self.query_one("#ratio", PlotextPlot), self.query_one("#innovation", PlotextPlot)
        for w in (ratio, inn):
            w.plt.clear_data()
            w.plt.clear_figure()
        p = ratio.plt
        t_ok = [s.t for s in samples if s.accepted]
        t_bad = [s.t for s in samples if not s.accepted]
        value = (lambda s: s.ratio) if gated else (lambda s: s.nis)
        if t_ok:
            p.plot(t_ok, [value(s) for s in samples if s.accepted], marker="braille", color="cyan")
        if t_bad:
            p.scatter(t_bad, [value(s) for s in samples if not s.accepted], marker="x", color="red")
        if gated:
            p.hline(1.0, "red")
            p.title("test ratio NIS/gate (gate = 1, red x rejected)")
        else:
            p.title("NIS (no gate)")
        q = inn.plt
        pts = [s for s in samples if len(s.y) > k]
        if pts:
            t = [s.t for s in pts]
            q.plot(t, [s.sd[k] for s in pts], marker="braille", color="gray", label="+sqrt(S)")
            q.plot(t, [-s.sd[k] for s in pts], marker="braille", color="gray", label="-sqrt(S)")
            q.plot(t, [s.y[k] for s in pts], marker="braille", color="cyan", label=f"y{k}")
        q.title(f"innovation y{k} with +-sqrt(S{k}{k})")
        q.xlabel("sensor time (s)")
        ratio.refresh()
        inn.refresh()
