"""The view's fixed-lag smoothed trace (``fusion tui --smooth-lag``), accumulated in the feed's worker.

Each smoothed estimate arrives ``lag`` s of sensor time after the live one (``fusion.smoothing.live``);
its (north, east) point joins a ring buffer decimated by sensor time like the live track, and its state
elements a second :class:`~fusion.tui.state_series.StateHistory`, which keeps more truth lines so that the
late estimates still find the truth around them.
"""
from __future__ import annotations

import math
from collections import deque
from typing import Callable

from fusion.api import Estimate, Message, StateLayout
from fusion.tui.state_series import StateHistory, StateSample


class SmoothedTrace:
    """``pos``: indices of north and east in the state (None: no horizontal position); ``track_dt``: s of
    sensor time between kept points; ``truth_keep``: truth lines kept for the late samples."""

    def __init__(self, layout: StateLayout, truth_names: Callable[[], list[str] | None], pos: tuple[int, int] | None,
                 max_track: int = 4000, track_dt: float = 0.1, truth_keep: int = 4096):
        self.pos = pos
        self.track: deque[tuple[float, float]] = deque(maxlen=max_track)
        self.total = 0
        self.track_dt = track_dt
        self._last_t = -math.inf
        self.states = StateHistory(layout, truth_names, truth_keep=truth_keep)

    def on_estimate(self, est: Estimate) -> None:
        self.states.on_estimate(est)
        if self.pos is not None and est.t - self._last_t >= self.track_dt:
            x = est.belief.x
            self.track.append((float(x[self.pos[0]]), float(x[self.pos[1]])))
            self.total += 1
            self._last_t = est.t

    def on_truth(self, msg: Message) -> None:
        self.states.on_truth(msg)

    def snapshot(self) -> tuple[tuple[tuple[float, float], ...], int, tuple[StateSample, ...]]:
        """(track points, points ever kept, state samples)."""
        return tuple(self.track), self.total, self.states.snapshot()
