"""What the live view shows at one instant: :class:`FeedSnapshot` (made by fusion.tui.feed.LiveFeed in its
worker thread, immutable, posted to the UI) and the :class:`LoggedEvent` entries of its event log."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Mapping

from fusion.api import Estimate
from fusion.tui.health import Health
from fusion.tui.series import Sample
from fusion.tui.state_series import StateSample

__all__ = ["FeedSnapshot", "LoggedEvent"]


@dataclass(frozen=True)
class LoggedEvent:
    """An event with its sequence number (so a view appends only the ones it has not shown)."""

    seq: int
    t: float
    kind: str
    sensor: str | None
    detail: str


@dataclass(frozen=True)
class FeedSnapshot:
    """Everything the view shows, at one instant. ``track``/``truth`` are (north, east) points in m,
    decimated to one per ``track_dt`` s of sensor time; ``track_total`` counts every point ever kept
    (a view that was reset hides the ones before its mark). ``state``: waiting, running, finished,
    reconnecting (a serial port being reopened: ``attempt``), lost (the source failed), stopped or error.
    ``health``: sensor rates and limits and the overall OK/DEGRADED/LOST; ``series``: innovation samples
    by sensor (fusion.tui.series); ``states``: estimate, 1-sigma and error against truth of the state
    elements (fusion.tui.state_series); ``attempt``: the reopen attempt while reconnecting.
    ``smooth_lag``: the fixed lag (s) of ``smoothed`` ((north, east) points in m, as ``track``) and
    ``smoothed_states`` (as ``states``), None when the view does not smooth. ``lag_s``: a live feed, how far
(s) the view has fallen behind the device (fusion.tui.feed.LiveFeed._lag; NaN for a replay)."""

    source: str
    live: bool
    state: str
    estimate: Estimate | None
    counters: dict[str, dict[str, int]]
    ignored: dict[str, int]
    rates: dict[str, float]
    events: tuple[LoggedEvent, ...]
    track: tuple[tuple[float, float], ...]
    track_total: int
    truth: tuple[tuple[float, float], ...]
    truth_total: int
    lines: int
    data_wall: float
    sensor_t: float
    speed_ratio: float
    wall: float = field(default_factory=time.monotonic)
    message: str = ""
    health: Health | None = None
    series: Mapping[str, tuple[Sample, ...]] = field(default_factory=dict)
    states: tuple[StateSample, ...] = ()
    attempt: int = 0
    smooth_lag: float | None = None
    smoothed: tuple[tuple[float, float], ...] = ()
    smoothed_total: int = 0
    smoothed_states: tuple[StateSample, ...] = ()
    lag_s: float = math.nan
