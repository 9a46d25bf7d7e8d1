"""The state plot: one state element over time. With truth in the stream, its error x_hat - x_true
between -3 sigma and +3 sigma (a consistent filter keeps ~99.7% of it inside); without truth, the
estimate with +-1 sigma around it (bias states: how well the bias is known). Key x chooses the element.
With ``fusion tui --smooth-lag L`` the fixed-lag smoothed error (or value) is a second trace (magenta),
L s behind the live one.
Drawn with textual-plotext, as the innovation plots (fusion.tui.innovation_plot says why)."""
from __future__ import annotations

import math
import time

from textual_plotext import PlotextPlot

from fusion.tui.state_series import StateSample


class StatePlot(PlotextPlot):
    """``names``: the elements that can be plotted (non-quaternion); ``element``: the index plotted."""

    DEFAULT_CSS = """
    StatePlot { height: 1fr; min-height: 8; border: round $primary-darken-2; }
    """

    def __init__(self, names: list[str], plot_hz: float = 4.0, **kwargs) -> None:
        super().__init__(**kwargs)
        self.names = names
        self.element = 0
        self.samples: tuple[StateSample, ...] = ()
        self.smoothed: tuple[StateSample, ...] = ()  # the fixed-lag smoothed samples (--smooth-lag)
        self.plot_dt = 1.0 / plot_hz if plot_hz > 0 else 0.0
        self._drawn = -math.inf
        self.border_title = "states  (x element)"

    def show(self, samples: tuple[StateSample, ...], force: bool = False,
             smoothed: tuple[StateSample, ...] = ()) -> None:
        """Take the live samples (and the smoothed ones); redraw at most ``plot_hz`` times a second."""
        self.samples = samples
        self.smoothed = smoothed
        now = time.monotonic()
        if force or now - self._drawn >= self.plot_dt:
            self._drawn = now
            self.draw()

    def next_element(self) -> None:
        if self.names:
            self.element = (self.element + 1) % len(self.names)
        self.draw()

    @property
    def has_truth(self) -> bool:
        k = self.element
        return any(len(s.err) > k and s.err[k] == s.err[k] for s in self.samples)

    def draw(self) -> None:
        p = self.plt
        p.clear_data()
        p.clear_figure()
        if not self.names:
            p.title("no plottable state elements")
            self.refresh()
            return
        k, name = self.element, self.names[self.element]
        pts = [s for s in self.samples if len(s.x) > k]
        t = [s.t for s in pts]
        if self.has_truth:
            good = [s for s in pts if s.err[k] == s.err[k]]
            tg = [s.t for s in good]
            p.plot(tg, [3.0 * s.sd[k] for s in good], marker="braille", color="gray")
            p.plot(tg, [-3.0 * s.sd[k] for s in good], marker="braille", color="gray")
            p.plot(tg, [s.err[k] for s in good], marker="braille", color="cyan")
            sm = [s for s in self.smoothed if len(s.err) > k and s.err[k] == s.err[k]]
            if sm:
                p.plot([s.t for s in sm], [s.err[k] for s in sm], marker="braille", color="magenta")
            p.title(f"error of {name} against truth, with +-3 sigma" + (", smoothed (magenta)" if sm else ""))
        elif pts:
            p.plot(t, [s.x[k] + s.sd[k] for s in pts], marker="braille", color="gray")
            p.plot(t, [s.x[k] - s.sd[k] for s in pts], marker="braille", color="gray")
            p.plot(t, [s.x[k] for s in pts], marker="braille", color="cyan")
            sm = [s for s in self.smoothed if len(s.x) > k]
            if sm:
                p.plot([s.t for s in sm], [s.x[k] for s in sm], marker="braille", color="magenta")
            p.title(f"{name} with +-1 sigma (no truth in the stream)" + (", smoothed (magenta)" if sm else ""))
        p.xlabel("sensor time (s)")
        self.border_title = f"states: {name}  (x element)"
        self.refresh()
