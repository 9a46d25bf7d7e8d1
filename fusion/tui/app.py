"""The live view: ``make_app(config, source)`` builds the Textual app used by ``fusion tui`` and the tests.

Layout: state table and per-sensor counters on the left, the track (top view) on the right, the event
log below them, a status line at the bottom. Keys: q quit, p pause (a replay stops; a live port keeps being read
and recorded, only the view freezes), r reset view (forget the trail and the event log shown so far).
"""
from __future__ import annotations

import itertools
import os
from pathlib import Path
from typing import Any, Iterator

from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.widgets import Footer, Header

from fusion.api import ConfigError
from fusion.config import System, load_system
from fusion.api import Source
from fusion.sources.select import open_source
from fusion.tui.counters import SensorCounters
from fusion.tui.event_log import EventLog
from fusion.tui.feed import FeedSnapshot, LiveFeed
from fusion.tui.messages import FeedUpdate
from fusion.tui.state_table import StateTable
from fusion.tui.status_line import StatusLine
from fusion.tui.track_plot import TrackPlot


class FusionApp(App):
    """Live state of one system over one source (a recording replay or a serial port)."""

    TITLE = "fusion"
    CSS = """
    #main { height: 1fr; }
    #left { width: 62; }
    StateTable, SensorCounters, EventLog { border: round $primary-darken-2; }
    EventLog { height: 10; }
    """
    BINDINGS = [
        Binding("q", "quit", "quit"),
        Binding("p", "pause", "pause/resume"),
        Binding("r", "reset_view", "reset view"),
    ]

    def __init__(self, system: System, feed_options: dict[str, Any]):
        super().__init__()
        self.system = system
        self.feed = LiveFeed(system, post=self._post_snapshot, **feed_options)
        self.latest: FeedSnapshot | None = None
        self.paused = False
        self.updates = 0  # snapshots handled (for tests: the UI is not flooded)
        lay = system.layout
        self._pos = (lay["p"].start, lay["p"].start + 1) if "p" in lay and lay.block("p").size >= 2 else None

    def _post_snapshot(self, snap: FeedSnapshot) -> None:  # called in the worker thread
        self.post_message(FeedUpdate(snap))

    def compose(self) -> ComposeResult:
        yield Header()
        with Horizontal(id="main"):
            with Vertical(id="left"):
                yield StateTable(self.system.layout)
                yield SensorCounters()
            yield TrackPlot(self.system.beacons, has_position=self._pos is not None)
        yield EventLog()
        yield StatusLine(self.system.filter.name)
        yield Footer()

    def on_mount(self) -> None:
        self.sub_title = f"{self.system.spec.name} · {self.system.filter.name}"
        self.run_worker(self.feed.run, name="feed", thread=True, exit_on_error=False)
        self.set_interval(0.5, self.query_one(StatusLine).tick)

    def on_unmount(self) -> None:
        self.feed.stop()

    def on_feed_update(self, message: FeedUpdate) -> None:
        self.latest = message.snapshot
        self.updates += 1
        if not self.paused:
            self._render(message.snapshot)

    def _render(self, snap: FeedSnapshot) -> None:
        self.query_one(StateTable).show(snap.estimate)
        self.query_one(SensorCounters).show(snap.counters, snap.ignored, snap.rates)
        self.query_one(EventLog).show(snap.events)
        current = None
        if snap.estimate is not None and self._pos is not None:
            x = snap.estimate.belief.x
            current = (float(x[self._pos[0]]), float(x[self._pos[1]]))
        self.query_one(TrackPlot).show(snap, current)
        self.query_one(StatusLine).show(snap, self.paused)

    def action_pause(self) -> None:
        """Pause or resume: a replay stops reading; a live port is still read (and recorded), the view freezes."""
        self.paused = not self.paused
        if self.paused:
            self.feed.pause()
        else:
            self.feed.resume()
        if self.latest is not None:
            if self.paused:
                self.query_one(StatusLine).show(self.latest, True)
            else:
                self._render(self.latest)

    def action_reset_view(self) -> None:
        self.query_one(TrackPlot).reset()
        self.query_one(EventLog).reset()

    async def action_quit(self) -> None:
        self.feed.stop()
        self.exit()


def _primed(lines: Iterator[str]) -> Iterator[str]:
    """Open a recording now (its InputError is raised here, before the UI starts), then stream it."""
    try:
        first = next(lines)
    except StopIteration:
        return iter(())
    return itertools.chain([first], lines)


def _label(path: Path) -> str:
    try:
        return os.path.relpath(path)
    except ValueError:  # another drive (Windows)
        return str(path)


def make_app(config_path_or_system: str | Path | System, source: Any = None, *, speed: float = 1.0,
             refresh_hz: float = 15.0, filter_override: Any = None) -> FusionApp:
    """The live view of a system over a source.

    ``config_path_or_system``: a system YAML (loaded with ``load_system``) or a wired ``System`` (fresh:
    every run works on its own copy). ``source``: None for the config's own recording, a recording path
    or any text ``--input`` takes (chosen through the registry: fusion.sources.select), or a Source
    object (e.g. ``fusion.sources.serial.SerialSource``). A recording is replayed at ``speed`` x real time
    by sensor time (0 = as fast as possible); a source with ``live = True`` is never paced. Opening
    errors (missing recording, dead port) raise ``InputError`` here, before the UI takes the terminal."""
    if isinstance(config_path_or_system, System):
        system = config_path_or_system
    else:
        system = load_system(config_path_or_system, filter_override=filter_override)
    if source is None:
        source = system.recording
        if source is None:
            raise ConfigError(f"{system.path or system.spec.name}: no 'recording:' in the config; "
                              "give a recording (--input LOG) or a serial port (--port PORT)")
    label = None
    if isinstance(source, (str, Path)):
        label = _label(Path(source)) if "://" not in str(source) else str(source)
        source = open_source(str(source), system.registry)
    if not isinstance(source, Source):
        raise ConfigError(f"source {source!r}: expected a path, a source URL or a fusion.api.Source")
    if hasattr(source, "open"):
        source.open()
    live = bool(source.live)
    lines = source.lines() if live else _primed(iter(source.lines()))
    options: dict[str, Any] = dict(lines=lines, source=label or source.label, live=live,
                                   close=getattr(source, "close", None))
    options.update(speed=speed, refresh_hz=refresh_hz)
    app = FusionApp(system, options)
    if hasattr(source, "on_idle"):
        source.on_idle = app.feed.idle  # a silent port still shows the last lines it sent
    return app
