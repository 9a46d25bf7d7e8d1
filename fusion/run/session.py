"""A run: a source's lines -> messages -> the loop (fusion.run.loop) -> sinks, hooks and statistics.
``fusion run``, ``fusion tui``, the experiments and the tests all run a system through here (docs/pipeline.md):
``run(system, source, sinks)`` over a whole source, or ``Run`` one message at a time for callers that pace it
(``run = Run(system); for item in iter_messages(lines, run.parsed): run.push(item); result = run.finish()``).

A run is a stream in bounded memory: estimates go to the sinks (and the ``fusion_on_estimate`` hook) and are
not kept; errors, NEES and NIS are accumulated online (fusion.run.stats); truth is a short window
(fusion.truth_stream). The wired ``System`` is not modified: running it twice gives identical results. What a
run leaves is fusion.run.result; the plugins' observers fusion.run.observers; the source's lines
fusion.run.lines; the checks of a recording's header against the config fusion.run.header.
"""
from __future__ import annotations

import copy
import itertools
import math
import time
from typing import Any, Callable, Iterable, Sequence

from fusion.api import Estimate, Event, FusionError, MalformedMessage, Message, ReceivesEvents, has
from fusion.config import System
from fusion.logformat import ParsedStream, parse_values
from fusion.run.header import (coverage_check, fields_warning, fix_sensor_absent, header_beacon_warnings,
                               truth_warnings)
from fusion.run.integrator import ProcessModelFailed
from fusion.run.loop import Loop, Updated
from fusion.run.observers import PASSED_ON, Observers, discard_outputs, is_own, read_only
from fusion.run.result import Collect, RunResult
from fusion.run.stats import COUNTERS, RunStats

__all__ = ["Run", "RunResult", "RunStats", "Collect", "COUNTERS"]



class Run:
    """One run of a system, fed one message at a time (``run()`` is the loop over a whole source).

    :param sinks: objects with ``on_estimate(estimate)`` (and optionally ``on_event(event)``:
        fusion.api.ReceivesEvents), e.g. the registered ``estimates`` sink; each gets every estimate.
        Closed by ``finish()``.
    :param on_event: called with every event (e.g. ``fusion run``'s notes on stderr).
    :param progress: called with the sensor time of every estimate (a progress bar).
    :param plot: a ``fusion.sinks.plot.PlotRecorder`` that keeps a decimated trajectory for ``--plot``.
    :param on_truth: called with every truth message (the live view draws the true track).
    :param hooks: call the plugins' observation hooks (``fusion_on_estimate``, ...).

    Observers cannot end the run: a plugin's hook implementation or a plugin's sink (a sink whose class is not
    fusion's own) that raises is named in ``plugin_errors`` (and the summary's ``plugin_errors``) and not
    called again; a failed sink's output files (the ``OutputFile`` objects it holds) are discarded, never
    left cut under their names. The run, fusion's own sinks and the summary go on complete. A sink's
    ``FusionError`` (a write that failed: disk full) is raised as before.
    """

    def __init__(self, system: System, sinks: Sequence[Any] = (), *, on_event: Callable[[Event], Any] | None = None,
                 progress: Callable[[float], Any] | None = None, plot: Any = None,
                 on_truth: Callable[[Message], Any] | None = None, hooks: bool = True, label: str = ""):
        self.system = system
        self.label = label
        self.parsed = ParsedStream(on_fields=self._check_fields)
        self._fields_told: set[str] = set()
        self.imu_coverage: dict[str, dict] = {}   # input sensor -> fusion.imu_coverage facts (summary health)
        self._header_open = True                   # until the first message: the '# fields' lines are all read
        self.stats: RunStats
        self.scheduler = self.loop = Loop(system)   # (``scheduler``: the name the live view reads it by)
        self.stats = RunStats(system, self.loop, self.parsed)
        self.sinks = list(sinks)
        # A plugin's sink (not one of fusion's own) sees read-only copies, as the hooks do (read_only)
        self._sink_views = [(s, not is_own(s)) for s in self.sinks]
        self._copies = any(foreign for _, foreign in self._sink_views)
        self._event_sinks = [(s, s.on_event, not is_own(s)) for s in self.sinks if has(s, ReceivesEvents)]
        self.plugin_errors: list[str] = []
        self.plugin_exceptions: list[BaseException] = []   # the same failures, for a traceback (--debug)
        self.on_event = on_event
        self.progress = progress
        self.plot = plot
        if plot is not None:
            self.stats.on_result = plot.on_result
        self.on_truth = on_truth
        pm = getattr(system.registry, "pm", None) if hooks else None
        self._hook_estimate = self._hook_event = self._hook_end = None
        if pm is not None:
            self._hook_estimate = Observers.of(pm, system.registry, "fusion_on_estimate", self)
            self._hook_event = Observers.of(pm, system.registry, "fusion_on_event", self)
            self._hook_end = Observers.of(pm, system.registry, "fusion_on_run_end", self)
        self.last: Estimate | None = None
        self.wall0 = time.perf_counter()
        self.finished: RunResult | None = None
        self._flushed = False
        self._unnamed: dict[str, int] = {}  # stream -> truth/reference lines without a "# fields" line

    @property
    def buffered(self) -> int:
        """Messages waiting in the reorder buffer (``scheduler.max_latency``), at most a bound."""
        return self.loop.buffered

    # ------------------------------------------------------------------ feeding
    def push(self, item: Message | MalformedMessage) -> list[Estimate | Event]:
        """Feed one message (or a malformed-line marker from ``iter_messages``); returns what it released,
        after the sinks, hooks and statistics have seen it."""
        if self._header_open and item.__class__ is Message:
            self._header_read()
        if item.__class__ is Message and (item.sensor == "truth" or item.sensor == "reference"):
            self._compare(item)
            return []
        outs = self.loop.push(item)
        if not outs:
            return []
        outs = list(outs)
        for out in outs:
            self._dispatch(out)
        return [o for o in outs if o.__class__ is not Updated]

    def consume(self, items: Iterable[Message | MalformedMessage]) -> None:
        """Feed every message of ``items`` (the fast loop of ``run()``)."""
        push = self.loop.push
        dispatch = self._dispatch
        if self._header_open:   # the header is read once the first message is: checks of it, once
            items = iter(items)
            first = next(items, None)
            if first is None:
                return
            self._header_read()
            items = itertools.chain((first,), items)
        for item in items:
            if item.__class__ is Message and (item.sensor == "truth" or item.sensor == "reference"):
                self._compare(item)
                continue
            for out in push(item):
                dispatch(out)

    def _compare(self, msg: Message) -> None:
        """A truth or reference line: through the same clock guard as the sensors (a jump of the
        recording's clock moves truth with it), then to its comparison."""
        sched = self.loop
        clock = sched.clock
        if clock.compared:   # held truth lines a sensor's decision released (the first after a pause)
            self._take_compared()
        newest = sched.newest
        t = msg.t
        stats = self.stats
        comp = stats.truth if msg.sensor == "truth" and stats.truth is not None else stats.comparison(msg.sensor)
        if not clock.busy and newest - clock.future_s <= t <= newest + clock.future_s:
            clock.on_base(msg.sensor)  # the common case, without building the lists admit() returns
            if comp is not None:
                comp.add_truth(msg)
            else:
                self._unnamed[msg.sensor] = self._unnamed.get(msg.sensor, 0) + 1
            if self.on_truth is not None and msg.sensor == "truth":
                self.on_truth(msg if msg.values.__class__ is not str else msg._replace(values=parse_values(msg.values)))
            return
        admitted, events = clock.admit(msg.sensor, msg, t, newest)
        for ev in events:
            self._dispatch(ev)
        self._add_compared(admitted)

    def _take_compared(self) -> None:
        """The truth and reference lines the clock guard released on another stream's decision."""
        self._add_compared(self.loop.clock.take_compared())

    def _add_compared(self, admitted: list[tuple[Message, float]]) -> None:
        stats = self.stats
        for m, t in admitted:
            if t != m.t:
                m = m._replace(t=t)
            comp = stats.truth if m.sensor == "truth" and stats.truth is not None else stats.comparison(m.sensor)
            if comp is not None:
                comp.add_truth(m)
            else:
                self._unnamed[m.sensor] = self._unnamed.get(m.sensor, 0) + 1
            if self.on_truth is not None and m.sensor == "truth":
                self.on_truth(m if m.values.__class__ is not str else m._replace(values=parse_values(m.values)))

    def _check_fields(self, sensor: str, names: tuple[str, ...], lineno: int) -> None:
        """A ``# fields SENSOR ...`` line against the names the sensor's reading component declares
        (``fields``, or the process's ``input_fields`` for the input): the same names in another order would
        be read by position, the columns silently swapped, so the stream is refused; other names get a
        warning (read by position)."""
        runtime = self.system.sensors.get(sensor)
        if runtime is None or not names:
            return
        if runtime.role == "input" and sensor not in self.imu_coverage:
            facts, warning = coverage_check(self.system, sensor, self.parsed.header.meta)
            if facts is not None:
                self.imu_coverage[sensor] = facts
            if warning is not None:
                self._dispatch(Event(math.nan, "warning", sensor, warning))
        warning = fields_warning(runtime, self.system.process, names, f"{self.label + ' ' if self.label else ''}"
                                 f"line {lineno}: '# fields {sensor} {' '.join(names)}'")
        if warning is not None and sensor not in self._fields_told:
            self._fields_told.add(sensor)
            self._dispatch(Event(math.nan, "warning", sensor, warning))

    def _header_read(self) -> None:
        """The first message: the header is read. A recording without ``initial.from_sensor``'s stream (a flight
        log without GPS) starts the filter without waiting for that fix, and one warning says so."""
        self._header_open = False
        absent = fix_sensor_absent(self.system, self.parsed.header.fields)
        if absent is not None:
            rate, warning = absent
            self.loop.start_without_fix(rate)
            self._dispatch(warning)

    def _updated(self, u: Updated) -> None:
        """An update's NIS: to the statistics (and a plot), not to the sinks."""
        self.stats.add_nis(u.sensor, u.t, u.nis, u.dim, u.accepted)
        self.stats.add_update(u.sensor, u.t, u.accepted)
        if self.plot is not None:
            self.plot.on_nis(u.sensor, u.t, u.nis, u.dim)

    def _dispatch(self, out: Estimate | Event | Updated) -> None:
        cls = out.__class__
        if cls is Updated:
            self._updated(out)   # type: ignore[arg-type]
        elif cls is Estimate:
            self.last = out
            self.stats.add_estimate(out)
            seen = read_only(out) if self._copies or self._hook_estimate is not None else out
            for sink, foreign in self._sink_views:
                if foreign:
                    try:
                        sink.on_estimate(seen)
                    except PASSED_ON:
                        raise
                    except Exception as exc:   # a plugin's sink: named, dropped, the run goes on
                        self._sink_failed(sink, "on_estimate", exc, out.t)
                else:
                    sink.on_estimate(out)
            if self._hook_estimate is not None:
                self._hook_estimate(estimate=seen, system=self.system)
            if self.progress is not None:
                self.progress(out.t)
        else:
            self.stats.add_event(out)
            if self.on_event is not None:
                self.on_event(out)
            for sink, on_event, foreign in self._event_sinks:
                if foreign:
                    try:
                        on_event(out)
                    except PASSED_ON:
                        raise
                    except Exception as exc:
                        self._sink_failed(sink, "on_event", exc, out.t)
                else:
                    on_event(out)
            if self._hook_event is not None:
                self._hook_event(event=out, system=self.system)

    def observers_gone(self, observers: Observers) -> None:
        """An observation hook none of whose implementations is left (each raised): not called any more."""
        if self._hook_estimate is observers:
            self._hook_estimate = None
        if self._hook_event is observers:
            self._hook_event = None
        if self._hook_end is observers:
            self._hook_end = None

    def plugin_failed(self, text: str, exc: BaseException) -> None:
        """A plugin's observer (a hook implementation, a sink) raised: named in the result, the run goes on."""
        self.plugin_errors.append(text)
        self.plugin_exceptions.append(exc)

    def _sink_failed(self, sink: Any, method: str, exc: BaseException, t: float = math.nan) -> None:
        """A plugin's sink raised: it gets nothing more, its output files are discarded (a cut file left
        under the name a later script reads would pass for a result), the failure is named."""
        self.sinks = [s for s in self.sinks if s is not sink]
        self._sink_views = [(s, f) for s, f in self._sink_views if s is not sink]
        self._copies = any(f for _, f in self._sink_views)
        self._event_sinks = [e for e in self._event_sinks if e[0] is not sink]
        inner = getattr(sink, "sink", sink)
        paths = discard_outputs(inner)
        registry = self.system.registry
        who = f"plugin sink {getattr(inner, 'name', None) or type(inner).__name__!r}"
        providers = getattr(registry, "providers", None) or {}
        provider = providers.get(type(inner).__module__.split(".")[0])   # its installed package, if one
        if provider:
            who += f" ({provider})"
        at = f" at t = {t:.3f} s" if math.isfinite(t) else ""
        lost = f"; its output {', '.join(paths)} was discarded (incomplete)" if paths else ""
        more = "" if method == "close" else "; it got nothing more"
        self.plugin_failed(f"{who}: its {method}() raised {type(exc).__name__}: {exc}{at}{more}{lost}", exc)

    def scheduler_finish(self) -> list[Estimate | Event]:
        """End of input: release what the scheduler still buffers (dispatched, and returned); ``finish()``
        then builds the result without flushing again."""
        outs = [] if self._flushed else list(self.loop.finish())
        self._flushed = True
        for out in outs:
            self._dispatch(out)
        return [o for o in outs if o.__class__ is not Updated]

    def finish(self, *, flush: bool = True, interrupted: bool = False, source_error: str | None = None,
               component_error: str | None = None) -> RunResult:
        """End the run: release what the scheduler still buffers (``flush``), close the sinks, build the
        summary (with ``source_error``, why the source stopped early, or ``component_error``, why the run
        did, if it did) and call ``fusion_on_run_end``. Idempotent."""
        if self.finished is not None:
            return self.finished
        try:
            if flush and not self._flushed:
                self._flushed = True
                try:
                    for out in self.loop.finish():
                        self._dispatch(out)
                except ProcessModelFailed as exc:   # while releasing what was buffered
                    component_error = component_error or str(exc)
            if self.loop.clock.compared:
                self._take_compared()
            for event in header_beacon_warnings(self.parsed.header.beacons, self.system.beacons):
                self._dispatch(event)
            for event in truth_warnings(self.stats, self._unnamed, self.system.layout.names):
                self._dispatch(event)
        finally:
            self.close_sinks()
        self.stats.finish()
        wall = time.perf_counter() - self.wall0
        summary = self.stats.summary(self.label, wall)
        if self.imu_coverage and isinstance(summary.get("health"), dict):
            summary["health"]["imu_coverage"] = self.imu_coverage
        if interrupted:
            summary["interrupted"] = True
        if source_error is not None:
            summary["source_error"] = source_error
        if component_error is not None:
            summary["component_error"] = component_error
        if self._hook_end is not None:
            # a copy: an observer that edits the dict it is given (pops a key to upload the rest) must not
            # change the table printed and the --summary-json written after it
            self._hook_end(summary=copy.deepcopy(summary), system=self.system)
        if self.plugin_errors:
            summary["plugin_errors"] = list(self.plugin_errors)
        self.finished = RunResult(summary, self.stats, self.last, self.parsed, interrupted, wall, source_error,
                                  component_error, tuple(self.plugin_errors), tuple(self.plugin_exceptions))
        return self.finished

    def close_sinks(self) -> None:
        """Close every sink: a sink's FusionError (a failed write) is raised after all are closed; a plugin's
        sink that raises anything else is a plugin error (``_sink_failed``: its outputs discarded)."""
        sinks, views = self.sinks, dict((id(s), f) for s, f in self._sink_views)
        self.sinks, self._sink_views, self._event_sinks = [], [], []
        errors = []
        for sink in sinks:
            try:
                sink.close()
            except FusionError as exc:
                errors.append(exc)
            except Exception as exc:
                if isinstance(exc, BrokenPipeError) or not views.get(id(sink), not is_own(sink)):
                    raise
                self._sink_failed(sink, "close", exc)
        if errors:
            raise errors[0]

