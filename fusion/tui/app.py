"""The live view: ``make_app(config, source)`` builds the Textual app used by ``fusion tui`` and the tests.

Layout, wide terminals (at least WIDE = 120 x 36 cells): state, per-sensor counters and health on the
left; the track (top view) and the innovation plots on the right; the event log below; a status line at
the bottom. Smaller terminals (down to 80 x 24) get the same panels as tabs (keys 1-6), each scrolling
rather than being cut. Keys: see ``FusionApp.BINDINGS`` (``?`` shows them all).
"""
from __future__ import annotations

import itertools
import os
from pathlib import Path
from typing import Any, Iterator

from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.css.query import NoMatches
from textual.css.scalar import Scalar
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.widgets import ContentSwitcher, Footer, Header, TabbedContent, TabPane

from fusion.api import Closes, ConfigError, Opens, ReportsIdle, ReportsStatus, Source, has
from fusion.config import System, load_system
from fusion.pipeline import source_text
from fusion.sources.select import open_source
from fusion.tui.counters import SensorCounters
from fusion.tui.event_log import EventLog
from fusion.tui.feed import LiveFeed
from fusion.tui.snapshot import FeedSnapshot
from fusion.tui.health_panel import HealthPanel
from fusion.tui.help_screen import HelpScreen
from fusion.tui.innovation_plot import InnovationPanel
from fusion.tui.messages import FeedUpdate
from fusion.tui.state_plot import StatePlot
from fusion.tui.state_table import StateTable
from fusion.tui.status_line import StatusLine
from fusion.tui.track_plot import TrackPlot

WIDE = (120, 36)  # cells: at least this wide and tall for the side-by-side layout
TABS = (("tab-state", "state"), ("tab-sensors", "sensors"), ("tab-track", "track"), ("tab-plots", "innovations"),
        ("tab-events", "events"), ("tab-states", "states"))


class FusionApp(App):
    """Live state of one system over one source (a recording replay or a serial port)."""

    TITLE = "fusion"
    CSS = """
    #main { height: 1fr; }
    #left { width: 62; }
    #state-scroll { height: auto; }
    #right { width: 1fr; }
    #right ContentSwitcher { height: 16; }
    #right InnovationPanel, #right StatePlot { height: 16; }
    StateTable, SensorCounters, HealthPanel, EventLog { border: round $primary-darken-2; }
    EventLog { height: 5; }
    Screen > EventLog { overflow-x: hidden; }
    TabbedContent { height: 1fr; }
    TabbedContent EventLog, TabbedContent TrackPlot, TabbedContent InnovationPanel { height: 1fr; }
    TabPane { padding: 0; }
    """
    BINDINGS = [
        Binding("q", "quit", "quit"),
        Binding("p", "pause", "pause"),
        Binding("n", "step", "step"),
        Binding("r", "reset_view", "reset"),
        Binding("s", "next_sensor", "sensor"),
        Binding("e", "next_element", "plot element", show=False),
        Binding("x", "next_state", "state element", show=False),
        Binding("v", "switch_plots", "innovations/states", show=False),
        Binding("f", "follow", "follow", show=False),
        Binding("plus,equals_sign", "zoom(2.0)", "zoom in", show=False),
        Binding("minus", "zoom(0.5)", "zoom out", show=False),
        Binding("0", "zoom(0)", "fit", show=False),
        *(Binding(str(i + 1), f"tab('{tid}')", f"{title} tab", show=False) for i, (tid, title) in enumerate(TABS)),
        Binding("question_mark", "help", "help"),
    ]
    HELP = [("q", "quit"), ("p", "pause / resume (a replay stops reading; a live port is still read and recorded)"),
            ("n", "single step: while a replay is paused, read on to the next estimate"),
            ("r", "reset view: forget the trail and the events shown so far"),
            ("s", "innovation plots: next sensor"), ("e", "innovation plots: next element of the innovation"),
            ("x", "state plot: next state element (error against truth with +-3 sigma, or value with +-1 sigma)"),
            ("v", "wide layout: show the innovation plots or the state plot"),
            ("f", "track: follow the current estimate (on/off)"), ("+ / -", "track: zoom in / out"),
            ("0", "track: fit everything"), ("1-6", "small terminals: tabs state, sensors, track, innovations, events, states"),
            ("?", "this help"), ("ctrl+p", "command palette")]

    def __init__(self, system: System, feed_options: dict[str, Any]):
        super().__init__()
        self.system = system
        self.feed = LiveFeed(system, post=self._post_snapshot, **feed_options)
        self.latest: FeedSnapshot | None = None
        self.paused = False
        self.updates = 0  # snapshots handled (for tests: the UI is not flooded)
        self.wide: bool | None = None  # the layout composed (None: not yet)
        lay = system.layout
        self._pos = (lay["p"].start, lay["p"].start + 1) if "p" in lay and lay.block("p").size >= 2 else None
        self._view: dict[str, Any] = {}  # view settings kept across a change of layout

    @property
    def _main(self):
        """The main screen (its widgets are updated while the help screen is shown over it)."""
        return self.screen_stack[0]

    def _post_snapshot(self, snap: FeedSnapshot) -> None:  # called in the worker thread
        self.post_message(FeedUpdate(snap))

    def _is_wide(self) -> bool:
        w, h = self.size
        return w >= WIDE[0] and h >= WIDE[1]

    def compose(self) -> ComposeResult:
        self.wide = self._is_wide()
        yield Header()
        state = StateTable(self.system.layout)
        counters, health = SensorCounters(), HealthPanel()
        track = TrackPlot(self.system.beacons, has_position=self._pos is not None)
        plots, events = InnovationPanel(), EventLog()
        states = StatePlot(list(self.feed.states.names))
        if self.wide:
            with Horizontal(id="main"):
                with Vertical(id="left"):
                    with VerticalScroll(id="state-scroll"):
                        yield state
                    yield counters
                    yield health
                with Vertical(id="right"):
                    yield track
                    with ContentSwitcher(initial="plots", id="plot-switch"):
                        plots.id = "plots"
                        states.id = "states"
                        yield plots
                        yield states
            yield events
        else:
            with TabbedContent(id="tabs"):
                with TabPane("1 state", id="tab-state"):
                    with VerticalScroll():
                        yield state
                with TabPane("2 sensors", id="tab-sensors"):
                    with VerticalScroll():
                        yield health
                        yield counters
                with TabPane("3 track", id="tab-track"):
                    yield track
                with TabPane("4 innovations", id="tab-plots"):
                    yield plots
                with TabPane("5 events", id="tab-events"):
                    yield events
                with TabPane("6 states", id="tab-states"):
                    yield states
        yield StatusLine(self.system.filter.name)
        yield Footer()

    def on_mount(self) -> None:
        self.sub_title = f"{self.system.spec.name} · {self.system.filter.name}"
        self.run_worker(self.feed.run, name="feed", thread=True, exit_on_error=False)
        self.set_interval(0.5, self._tick)

    async def _tick(self) -> None:
        if not self.screen_stack:  # a timer firing during teardown: no screen left to draw on
            return
        for line in self._main.query(StatusLine):
            line.tick()
        self._fit_state()
        await self._relayout()

    def _fit_state(self) -> None:
        """Wide layout: the state table gets what the sensors and health panels leave of the left column, and
        scrolls within it when longer (a long state, 17 elements at 120 x 40, never pushes the health panel
        out of view)."""
        found = self._main.query("#state-scroll")
        if not found:
            return
        box = found.first()
        left = box.parent
        rest = sum(w.outer_size.height for w in left.children if w is not box)
        room = max(4, left.size.height - rest)
        if left.size.height and box.styles.max_height != Scalar.parse(str(room)):
            box.styles.max_height = room

    async def _relayout(self) -> None:
        """Switch between the wide layout and the tabs when the terminal crossed WIDE (checked twice a second)."""
        if self.wide is not None and self._is_wide() != self.wide and self.screen is self._main:
            self._keep_view()
            await self.recompose()
            self._restore_view()

    def _keep_view(self) -> None:
        track, plots = self._main.query_one(TrackPlot), self._main.query_one(InnovationPanel)
        self._view = dict(zoom=track.zoom, follow=track.follow, hide=track.hidden,
                          sensor=plots.sensor, element=plots.element,
                          state=self._main.query_one(StatePlot).element)

    def _restore_view(self) -> None:
        v = self._view
        if v:
            track, plots = self._main.query_one(TrackPlot), self._main.query_one(InnovationPanel)
            track.zoom, track.follow = v["zoom"], v["follow"]
            track.hidden = v["hide"]
            plots.sensor, plots.element = v["sensor"], v["element"]
            self._main.query_one(StatePlot).element = v["state"]
        if self.latest is not None:
            self._render(self.latest, force=True)

    def on_unmount(self) -> None:
        self.feed.stop()

    def on_feed_update(self, message: FeedUpdate) -> None:
        self.latest = message.snapshot
        self.updates += 1
        if self.feed.paused and not self.paused:  # the feed held itself (pause_at)
            self.paused = True
        only_status = not (not self.paused or self.feed.stepping or message.snapshot.state not in ("running", "waiting"))
        if not self.screen_stack:  # before the first screen or after the last: nothing to draw
            return
        try:
            self._render(message.snapshot, only_status=only_status)
        except NoMatches:  # an update from the feed's thread racing the screen's mount or teardown: nothing to draw
            return

    def _render(self, snap: FeedSnapshot, force: bool = False, only_status: bool = False) -> None:
        if only_status and not self.feed.live:  # a paused replay: a single step still shows
            only_status = False
        if only_status:
            self._main.query_one(StatusLine).show(snap, True)
            return
        self._main.query_one(StateTable).show(snap.estimate)
        self._main.query_one(SensorCounters).show(snap.counters, snap.ignored, snap.rates)
        self._main.query_one(HealthPanel).show(snap.health)
        self._main.query_one(EventLog).show(snap.events)
        current = cov = None
        if snap.estimate is not None and self._pos is not None:
            x = snap.estimate.belief.x
            i, j = self._pos
            current = (float(x[i]), float(x[j]))
            cov = snap.estimate.belief.cov[[i, j]][:, [i, j]]
        self._main.query_one(TrackPlot).show(snap, current, cov)
        self._main.query_one(InnovationPanel).show(snap.series, force=force or self.paused)
        self._main.query_one(StatePlot).show(snap.states, force=force or self.paused, smoothed=snap.smoothed_states)
        self._main.query_one(StatusLine).show(snap, self.paused)
        self.call_after_refresh(self._fit_state)   # the panels under the state may have grown a row

    def action_pause(self) -> None:
        """Pause or resume: a replay stops reading; a live port is still read (and recorded), the view freezes."""
        self.paused = not self.paused
        if self.paused:
            self.feed.pause()
        else:
            self.feed.resume()
        if self.latest is not None:
            if self.paused:
                self._main.query_one(StatusLine).show(self.latest, True)
            else:
                self._render(self.latest)

    def action_step(self) -> None:
        if self.feed.live:
            self.notify("single step works on replays; a live port keeps being read", severity="warning")
        elif not self.paused:
            self.action_pause()  # the first n pauses; the next ones step
        else:
            self.feed.step()

    def action_reset_view(self) -> None:
        self._main.query_one(TrackPlot).reset()
        self._main.query_one(EventLog).reset()

    def action_next_sensor(self) -> None:
        self._main.query_one(InnovationPanel).next_sensor()

    def action_next_element(self) -> None:
        self._main.query_one(InnovationPanel).next_element()

    def action_next_state(self) -> None:
        self._main.query_one(StatePlot).next_element()

    def action_switch_plots(self) -> None:
        for switcher in self._main.query("#plot-switch"):
            switcher.current = "states" if switcher.current == "plots" else "plots"

    def action_follow(self) -> None:
        self._main.query_one(TrackPlot).toggle_follow()

    def action_zoom(self, factor: float) -> None:
        track = self._main.query_one(TrackPlot)
        if factor == 0:
            track.zoom, track.follow = 1.0, False
            track.refresh()
        else:
            track.set_zoom(factor)

    def action_tab(self, tab: str) -> None:
        for tabs in self._main.query(TabbedContent):
            tabs.active = tab

    def action_help(self) -> None:
        if not isinstance(self.screen, HelpScreen):
            self.push_screen(HelpScreen(self.HELP))

    async def action_quit(self) -> None:
        self.feed.stop()
        self.exit()


def _primed(lines: Iterator[str], label: str = "") -> Iterator[str]:
    """Open a recording now (its InputError is raised here, before the UI starts), then stream it. A source
    whose first read fails (an OSError: a link down) is an InputError naming it, as in ``fusion run``."""
    from fusion.errors import InputError
    from fusion.pipeline import _source_message

    try:
        first = next(lines)
    except StopIteration:
        return iter(())
    except OSError as exc:
        raise InputError(_source_message(label, exc)) from None
    return itertools.chain([first], lines)


def _label(path: Path) -> str:
    try:
        return os.path.relpath(path)
    except ValueError:  # another drive (Windows)
        return str(path)


def make_app(config_path_or_system: str | Path | System, source: Any = None, *, speed: float = 1.0,
             refresh_hz: float = 15.0, filter_override: Any = None, udp: str | None = None,
             expected_rates: dict[str, float] | None = None, limits: dict[str, float] | None = None,
             pause_at: float | None = None, smooth_lag: float | None = None) -> FusionApp:
    """The live view of a system over a source.

    ``config_path_or_system``: a system YAML (loaded with ``load_system``) or a wired ``System`` (fresh:
    every run works on its own copy). ``source``: None for the config's own recording, a recording path
    or any text ``--input`` takes (chosen through the registry: fusion.sources.select), or a Source
    object (e.g. ``fusion.sources.serial.SerialSource``). A recording is replayed at ``speed`` x real time
    by sensor time (0 = as fast as possible); a source with ``live = True`` is never paced. Opening
    errors (missing recording, dead port) raise ``InputError`` here, before the UI takes the terminal.
    ``udp``: ``HOST:PORT`` to stream every estimate as JSON (fusion.tui.udp); ``expected_rates`` (Hz)
    and ``limits`` (s) by sensor for the health; ``pause_at``: a replay pauses itself after the first
    message at or after this sensor time (s), for pictures at a fixed replay time; ``smooth_lag``: s of
    sensor time by which a fixed-lag smoothed trace follows the live one in the track and the state plot
    (``fusion tui --smooth-lag``; None: no smoothing)."""
    if isinstance(config_path_or_system, System):
        system = config_path_or_system
    else:
        from fusion.config import OWN_RECORDING
        from fusion.header_checks import check as check_header

        # the world (magnetic field, receivers...) of what is replayed, not the config's own recording's
        given = OWN_RECORDING if source is None else str(source) if isinstance(source, (str, Path)) else None
        system = load_system(config_path_or_system, filter_override=filter_override, recording=given)
        check_header(system, system.world, str(config_path_or_system))
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
    if has(source, Opens):
        source.open()
    live = bool(source.live)
    label = label or source.label
    lines = source_text(source.lines(), source, label)   # a plugin's source yielding bytes: named, exit 2
    lines = lines if live else _primed(iter(lines), label)
    options: dict[str, Any] = dict(lines=lines, source=label, live=live,
                                   close=source.close if has(source, Closes) else None)
    options.update(speed=speed, refresh_hz=refresh_hz, expected_rates=expected_rates, limits=limits,
                   pause_at=pause_at, smooth_lag=smooth_lag)
    _check_sensors(system, expected_rates, "--expect-rate")
    _check_sensors(system, limits, "--limit")
    if udp:
        from fusion.tui.udp import UdpStream, parse_address

        host, port = parse_address(udp)
        options["sinks"] = [UdpStream(host, port, system.layout,
                                      {n: s.gate for n, s in system.sensors.items() if s.gate is not None})]
    app = FusionApp(system, options)
    if has(source, ReportsIdle):
        source.on_idle = app.feed.idle  # a silent port still shows the last lines it sent
    if has(source, ReportsStatus):
        source.on_status = app.feed.source_status  # RECONNECTING (attempt N) while a lost port is retried
    return app


def _check_sensors(system: System, values: dict[str, float] | None, option: str) -> None:
    for name in values or {}:
        if name not in system.sensors:
            raise ConfigError(f"{option} {name}=...: no sensor {name!r} in the config "
                              f"(sensors: {', '.join(system.sensors)})")
