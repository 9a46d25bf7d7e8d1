"""A run: a source's lines -> messages -> the loop (fusion.run.loop) -> sinks, hooks and statistics.

    from fusion.config import load_system
    from fusion import pipeline

    system = load_system("configs/abps_ins.yaml")
    result = pipeline.run(system, system.recording)          # or a Source, or any iterable of lines
    result.summary["errors"]["position_rmse_m"]

``fusion run``, ``fusion tui``, the experiments and the tests all run a system through this module;
nothing else drives a ``Loop``. A run is a stream in bounded memory: estimates go to the sinks (and
to the ``fusion_on_estimate`` hook) and are not kept; errors against truth, NEES and NIS are accumulated
online (``RunStats``); truth is kept as a short window for interpolation (``fusion.truth_stream``); a plot
keeps a decimated trajectory of bounded size. The wired ``System`` is not modified: running it twice gives
identical results.

``Run`` is the same loop one message at a time, for callers that pace or interleave it (the live view):
``run = Run(system); for item in iter_messages(lines, run.parsed): run.push(item); result = run.finish()``.

Modules: this one is the loop (``Run``, ``run``, ``RunResult``, the ``Collect`` sink); what a run counts is
``fusion.run.stats.RunStats`` and its summary dict ``fusion.run_summary`` (both importable from here).
"""
from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Sequence

import numpy as np

from fusion.api import (Belief, Closes, Estimate, Event, FusionError, InputError, MalformedMessage, Message, Opens,
                        ReceivesEvents, Source, UpdateResult, has)
from fusion.run.clock import COMPARED
from fusion.config import System
from fusion.logformat import ParsedStream, iter_messages, parse_values
from fusion.run.integrator import ProcessModelFailed
from fusion.run.loop import Loop, Updated
from fusion.run.stats import COUNTERS, RunStats

__all__ = ["run", "Run", "RunResult", "RunStats", "Collect", "COUNTERS"]



class Collect:
    """A sink that keeps every estimate (``estimates``) and event (``events``) in memory: for tests,
    experiments and short runs that want arrays afterwards. It is the one place a run's memory grows
    with its length, and only when asked for."""

    def __init__(self) -> None:
        self.estimates: list[Estimate] = []
        self.events: list[Event] = []

    def on_estimate(self, estimate: Estimate) -> None:
        self.estimates.append(estimate)

    def on_event(self, event: Event) -> None:
        self.events.append(event)

    def close(self) -> None:
        pass

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(t (k,), x (k, n), sd (k, n))`` of the collected estimates."""
        est = self.estimates
        n = est[0].belief.x.size if est else 0
        return (np.array([e.t for e in est]), np.array([e.belief.x for e in est]).reshape(-1, n),
                np.array([e.belief.sd for e in est]).reshape(-1, n))


@dataclass
class RunResult:
    """What a run leaves: its ``summary`` (the ``--summary-json`` dict), its ``stats``, the ``last``
    estimate (None when there was none), the parse state (``parsed``: header and malformed lines),
    ``interrupted`` (Ctrl-C), the wall time, and ``source_error``: why the source stopped early (it raised
    an OSError or a FusionError, e.g. a lost link), None when it ended normally; ``component_error``: why the
    run stopped before the end of its input because a component cannot go on (the process model failed on
    every prediction: fusion.run.integrator.ProcessModelFailed), None otherwise; ``plugin_errors``: one line per
    observer of a plugin that raised (an observation hook, a plugin's sink), each naming the plugin: the
    run went on without it (``Run``), so the estimates and the summary are complete."""

    summary: dict[str, Any]
    stats: RunStats
    last: Estimate | None
    parsed: ParsedStream
    interrupted: bool
    wall_s: float
    source_error: str | None = None
    component_error: str | None = None
    plugin_errors: tuple[str, ...] = ()
    plugin_exceptions: tuple[BaseException, ...] = field(default=(), repr=False)


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
        self.stats: RunStats
        self.scheduler = self.loop = Loop(system)   # (``scheduler``: the name the live view reads it by)
        self.stats = RunStats(system, self.loop, self.parsed)
        self.sinks = list(sinks)
        # A plugin's sink (not one of fusion's own) sees read-only copies, as the hooks do (read_only)
        self._sink_views = [(s, not _is_own(s)) for s in self.sinks]
        self._copies = any(foreign for _, foreign in self._sink_views)
        self._event_sinks = [(s, s.on_event, not _is_own(s)) for s in self.sinks if has(s, ReceivesEvents)]
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
            self._hook_estimate = _Observers.of(pm, system.registry, "fusion_on_estimate", self)
            self._hook_event = _Observers.of(pm, system.registry, "fusion_on_event", self)
            self._hook_end = _Observers.of(pm, system.registry, "fusion_on_run_end", self)
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
        expected, who = expected_fields(runtime, self.system.process)
        if expected is None or tuple(names) == tuple(expected):
            return
        line = f"{self.label + ' ' if self.label else ''}line {lineno}: '# fields {sensor} {' '.join(names)}'"
        if sorted(names) == sorted(expected):
            raise InputError(f"{line} names the values in another order than {who} reads them "
                             f"({' '.join(expected)}): they would be swapped; reorder the columns (or the "
                             f"importer's mapping) to {' '.join(expected)}")
        if sensor not in self._fields_told:
            self._fields_told.add(sensor)
            self._dispatch(Event(math.nan, "warning", sensor, f"{line}: {who} reads {' '.join(expected)}; the "
                                 "values are read in that order, by position"))

    def _updated(self, u: Updated) -> None:
        """An update's NIS: to the statistics (and a plot), not to the sinks."""
        self.stats.add_nis(u.sensor, u.t, u.nis, u.dim, u.accepted)
        self.stats.add_update(u.sensor, u.t, u.accepted)
        if self.plot is not None:
            self.plot.on_nis(u.sensor, u.t, u.nis, u.dim)

    def _dispatch(self, out: Estimate | Event | Updated) -> None:
        if out.__class__ is Updated:
            self._updated(out)   # type: ignore[arg-type]
        elif out.__class__ is Estimate:
            self.last = out
            self.stats.add_estimate(out)
            seen = read_only(out) if self._copies or self._hook_estimate is not None else out
            for sink, foreign in self._sink_views:
                if foreign:
                    try:
                        sink.on_estimate(seen)
                    except _PASSED_ON:
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
                    except _PASSED_ON:
                        raise
                    except Exception as exc:
                        self._sink_failed(sink, "on_event", exc, out.t)
                else:
                    on_event(out)
            if self._hook_event is not None:
                self._hook_event(event=out, system=self.system)

    def _plugin_failed(self, text: str, exc: BaseException) -> None:
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
        paths = _discard_outputs(inner)
        registry = self.system.registry
        who = f"plugin sink {getattr(inner, 'name', None) or type(inner).__name__!r}"
        providers = getattr(registry, "providers", None) or {}
        provider = providers.get(type(inner).__module__.split(".")[0])   # its installed package, if one
        if provider:
            who += f" ({provider})"
        at = f" at t = {t:.3f} s" if math.isfinite(t) else ""
        lost = f"; its output {', '.join(paths)} was discarded (incomplete)" if paths else ""
        more = "" if method == "close" else "; it got nothing more"
        self._plugin_failed(f"{who}: its {method}() raised {type(exc).__name__}: {exc}{at}{more}{lost}", exc)

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
        if interrupted:
            summary["interrupted"] = True
        if source_error is not None:
            summary["source_error"] = source_error
        if component_error is not None:
            summary["component_error"] = component_error
        if self._hook_end is not None:
            # a copy: an observer that edits the dict it is given (pops a key to upload the rest) must not
            # change the table printed and the --summary-json written after it (tester6 #2)
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
                if isinstance(exc, BrokenPipeError) or not views.get(id(sink), not _is_own(sink)):
                    raise
                self._sink_failed(sink, "close", exc)
        if errors:
            raise errors[0]


def expected_fields(runtime: Any, process: Any) -> tuple[tuple[str, ...] | None, str]:
    """(the names of the values a sensor's messages are read as, in order, and the component that reads
    them), or (None, "") when none declares them: the input's process (``input_fields``), else the first of
    the sensor's decoder, preprocessor and model that declares ``fields`` (past the decoder only when it is
    ``line``, which passes the values on as they are: another decoder's output is not the line's values)."""
    if runtime.role == "input":
        names = getattr(process, "input_fields", None)
        return (tuple(names), f"process {process.name!r}") if names else (None, "")
    chain = (runtime.decoder, runtime.preprocessor, runtime.model)
    if runtime.decoder is not None and runtime.decoder.name != "line":
        chain = (runtime.decoder,)
    for comp in chain:
        names = getattr(comp, "fields", None) if comp is not None else None
        if names:
            return tuple(names), f"{comp.kind} {comp.name!r}"
    return None, ""


def truth_warnings(stats: RunStats, unnamed: dict[str, int], state_names: Sequence[str]) -> list[Event]:
    """Warnings when truth (or reference) lines could not be compared: no ``# fields`` line names their
    columns, or truth has columns that are no state element while it lacks the state's position elements,
    or all of them (``x y`` for a state's ``px py``: a naming mismatch, not a state truth cannot give)."""
    events = []
    for stream, n in sorted(unnamed.items()):
        events.append(Event(math.nan, "warning", None, f"{n} {stream} line(s) but no '# fields {stream} ...' "
                            f"header line names their columns: not compared (the state's elements: "
                            f"{' '.join(state_names)})"))
    for stream, comp in (("truth", stats.truth), ("reference", stats.reference)):
        if comp is None:
            continue
        names = list(comp.window.names)
        foreign = [c for c in names if c not in state_names]
        absent = [n for n in state_names if n not in names]
        position = comp.tracker.position_group()
        if foreign and (len(absent) == len(state_names) or any(n in absent for n in position)):
            events.append(Event(math.nan, "warning", None, f"{stream} columns {' '.join(foreign)} are no element "
                                f"of the state, and the state's {' '.join(absent)} are not among the {stream} "
                                "columns: those are not compared (a column is compared when it has the "
                                "element's name)"))
        comp.flush()   # the estimates evaluated so far, scored (TruthComparison.SCORE_BATCH): their count
        w, compared = comp.window, comp.tracker.compared
        if w.received >= 2 and w.period > COARSE_TRUTH_S and compared > 2 * w.received:
            T = w.period
            events.append(Event(math.nan, "warning", None, f"{stream} every {T:.3g} s, sparser than the estimates "
                                f"({compared} compared against {w.received} {stream} samples): an error between "
                                f"two {stream} samples includes the linear interpolation's own (a T^2/8 for an "
                                f"acceleration a: {0.125 * T * T:.2g} m at 1 m/s^2)"))
    return events


#: Truth sample period (s) beyond which the end of a run warns that errors between samples include the
#: interpolation's: a T^2 / 8 at acceleration a, 5 mm at 1 m/s^2 for 0.2 s, the order of the best fixes here.
COARSE_TRUTH_S = 0.2


#: Distance (m) between a recording's declared beacon and the config's beyond which they disagree.
BEACON_TOLERANCE_M = 0.01


def header_beacon_warnings(declared: dict[str, tuple[float, ...]], configured: dict[str, np.ndarray]) -> list[Event]:
    """Warnings when the recording's header (``# beacon B5: x y z``, as ``fusion simulate`` writes it) names a
    beacon the config lacks (its ranges are all malformed) or puts one elsewhere than the config does (every
    range to it is then wrong by up to the distance). Nothing when the config has no beacons."""
    if not configured:
        return []
    events = []
    missing = [b for b in declared if b not in configured]
    if missing:
        events.append(Event(math.nan, "warning", None, f"the recording declares beacon(s) {', '.join(missing)} that "
                            f"the config does not define (defined: {', '.join(sorted(configured))})"))
    for name, pos in declared.items():
        mine = configured.get(name)
        if mine is None:
            continue
        d = len(mine)
        theirs = np.asarray(pos[:d] if len(pos) >= d else tuple(pos) + (0.0,) * (d - len(pos)), float)
        gap = float(np.linalg.norm(theirs - mine))
        if not gap <= BEACON_TOLERANCE_M:
            events.append(Event(math.nan, "warning", None, f"beacon {name} is at {list(map(float, pos))} in the "
                                f"recording's header and at {mine.tolist()} in the config ({gap:.3g} m apart)"))
    return events


#: What an observer's failure is not: a FusionError (the user's to fix: a failed write, raised as before) and
#: a BrokenPipeError (a plugin printing to a stdout whose reader went away: the CLI ends quietly, exit 141).
_PASSED_ON = (FusionError, BrokenPipeError)


class _Observers:
    """The implementations of one observation hook, called one by one in pluggy's order (the last
    registered first): one that raises is named in the run's ``plugin_errors`` and not called again, the
    others and the run go on (an observer cannot end the run, nor lose its outputs: tester6 #10)."""

    def __init__(self, name: str, impls: list[tuple[Callable, tuple[str, ...] | None, str]], run: "Run"):
        self.name = name
        self.impls = impls
        self.run = run

    @classmethod
    def of(cls, pm: Any, registry: Any, name: str, run: "Run") -> "_Observers | None":
        """The hook's implementations, None when there is none."""
        found = getattr(pm.hook, name).get_hookimpls()
        if not found:
            return None
        if any(hi.hookwrapper or getattr(hi, "wrapper", False) for hi in found):
            hook = getattr(pm.hook, name)   # a wrapper needs pluggy's own call; one failure is still named
            return cls(name, [(hook, None, f"a plugin's {name} hook")], run)
        providers = getattr(registry, "providers", {}) or {}
        impls = []
        for hi in reversed(found):
            impls.append((hi.function, tuple(hi.argnames), _plugin_label(pm, hi.plugin, providers)))
        return cls(name, impls, run)

    def __call__(self, **kwargs: Any) -> None:
        for impl in self.impls:
            fn, names, who = impl
            try:
                if names is None:
                    fn(**kwargs)
                else:
                    fn(*[kwargs[a] for a in names])
            except _PASSED_ON:
                raise
            except Exception as exc:
                self._failed(impl, exc, kwargs)

    def _failed(self, impl: tuple, exc: BaseException, kwargs: dict[str, Any]) -> None:
        self.impls = [i for i in self.impls if i is not impl]
        item = kwargs.get("estimate", kwargs.get("event"))
        t = getattr(item, "t", math.nan)
        at = f" at t = {t:.3f} s" if isinstance(t, float) and math.isfinite(t) else (
            " at the end of the run" if self.name == "fusion_on_run_end" else "")
        again = "" if self.name == "fusion_on_run_end" else "; it was not called again"
        self.run._plugin_failed(f"{impl[2]}: its {self.name} hook raised {type(exc).__name__}: {exc}{at}{again}", exc)
        if not self.impls:    # none left: the run stops copying estimates for it
            for attr in ("_hook_estimate", "_hook_event", "_hook_end"):
                if getattr(self.run, attr) is self:
                    setattr(self.run, attr, None)


def _plugin_label(pm: Any, plugin: Any, providers: dict[str, str]) -> str:
    """``plugin t6 (fusion-t6 0.1.0)``: the entry point's name and the distribution that installed it."""
    name = pm.get_name(plugin) or ""
    if not name or name.isdigit():   # registered without a name (pluggy names it by id): its module or class
        name = getattr(plugin, "__name__", None) or type(plugin).__qualname__
    top = (getattr(plugin, "__name__", None) or type(plugin).__module__).split(".")[0]
    package = providers.get(top)
    return f"plugin {name}" + (f" ({package})" if package else "")


def _discard_outputs(sink: Any) -> list[str]:
    """Discard the ``fusion.api.OutputFile`` objects a (failed) sink holds as attributes; their paths."""
    from fusion.outputs import OutputFile

    paths = []
    for value in list(getattr(sink, "__dict__", {}).values()):
        if isinstance(value, OutputFile):
            if value.temporary is not None or value.file is not None:
                paths.append(value.path)
            value.discard()
    return paths


def _is_own(sink: Any) -> bool:
    """A sink of fusion itself (its CSV, JSON lines, plot and summary sinks, or their wrappers): trusted not to
    write into the arrays it is given; any other (a plugin's) gets read-only copies."""
    inner = getattr(sink, "sink", sink)      # guard_sink and similar wrappers keep the sink they guard
    mod = type(inner).__module__
    return mod == "fusion" or mod.startswith("fusion.")


def _frozen(a: Any) -> Any:
    if isinstance(a, np.ndarray):
        a = a.copy()
        a.flags.writeable = False
    return a


def read_only(estimate: Estimate) -> Estimate:
    """A copy of ``estimate`` whose arrays (the belief's x, P or S; the update's innovation and S) are
    read-only: what an observation hook or a plugin's sink is given (docs/writing-plugins.md: the objects
    are immutable). A hook that wrote into ``estimate.belief.x`` wrote into the filter's own state, and every
    later estimate started from it (tester3 #13: RMSE 0.11 m -> 693 km, exit 0); now it raises
    ``ValueError: assignment destination is read-only`` in the plugin, named by the run."""
    b = estimate.belief
    belief = Belief(b.t, _frozen(b.x), P=_frozen(b.P), S=_frozen(b.S), events=b.events)
    u = estimate.update
    if u is not None:
        u = UpdateResult(belief if u.belief is b else u.belief, _frozen(u.innovation), _frozen(u.S), u.nis,
                         u.accepted, events=u.events, iterations=u.iterations)
    return Estimate(estimate.t, belief, estimate.reason, estimate.sensor, u)


def _lines_of(source: Any, given: str | None = None) -> tuple[Iterable[str], str, Callable[[], Any] | None]:
    """(lines, label, close) of a path, a Source or an iterable of text lines. A source without a ``label`` of
    its own is named by ``given`` (the text the user typed, ``gen://5``) rather than by the default label, its
    first parameter's value (tester6 #14: "5.0"). A plugin's source's lines are checked to be text."""
    if isinstance(source, (str, Path)):
        from fusion.sources.select import open_source

        source = open_source(str(source))
    if isinstance(source, Source):
        if has(source, Opens):
            source.open()
        if given and type(source).label is Source.label:
            label = given
        else:
            label = source.label or str(getattr(source.params, "path", "") or source.name)
        label = str(label)
        return source_text(source.lines(), source, label), label, source.close if has(source, Closes) else None
    return source, "<lines>", None


def source_text(lines: Iterable[Any], source: Source, label: str) -> Iterable[str]:
    """A plugin's source's ``lines()`` checked to be text: one that yields bytes or anything else (a socket's
    datagrams undecoded) ends the input with an InputError naming the source and what it yielded, where the
    parser would fail on it as an internal error (tester6 #14). fusion's own sources are not re-checked."""
    if _is_own(source):
        return lines
    return _text_only(lines, source, label)


def _text_only(lines: Iterable[Any], source: Source, label: str) -> Iterator[str]:
    for n, line in enumerate(lines, 1):
        if not isinstance(line, str):
            what = type(line).__name__
            hint = " (decode it: line.decode('utf-8'))" if isinstance(line, (bytes, bytearray)) else ""
            raise InputError(f"source {source.name!r} ({label}) yielded {what} {_short(line)} as line {n}: a "
                             f"source's lines() yields text (str){hint}")
        yield line


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


class _SourceLost(Exception):
    """The source's own iteration raised (``__cause__``): a lost link, a vanished file, a source's
    InputError. Told apart from a component's failure, which the same loop would otherwise see."""


def _guarded(lines: Iterable[str]) -> Iterator[str]:
    try:
        yield from lines
    except (OSError, FusionError) as exc:
        raise _SourceLost(str(exc)) from exc


def _source_message(name: str, exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        text = exc.strerror + (f": {exc.filename}" if exc.filename else "")
    else:
        text = str(exc) or type(exc).__name__
    return text if name and name in text else f"{name}: {text}"


def run(system: System, source: Any, sinks: Sequence[Any] = (), *, on_event: Callable[[Event], Any] | None = None,
        progress: Callable[[float], Any] | None = None, plot: Any = None, hooks: bool = True,
        label: str | None = None, on_truth: Callable[[Message], Any] | None = None) -> RunResult:
    """Run ``system`` over ``source`` (a recording path or source URL, a ``Source``, or an iterable of text
    lines) and return its ``RunResult``. ``sinks`` get every estimate and are closed at the end;
    ``on_truth`` every truth message, on the stream's time base (as ``Run``'s).

    Ctrl-C stops reading: what was read is processed, the sinks are closed and the result has
    ``interrupted=True``. A source that fails while it is read (an OSError or a FusionError from its lines,
    e.g. a lost link) ends the run the same way, what was read processed and summarised, the hooks
    called, with ``source_error`` saying why (``fusion run`` then exits 2). A process model that fails on
    every prediction (fusion.run.integrator.ProcessModelFailed) ends it so too, with ``component_error``; a
    model's failure in one update only loses that message (fusion.run.measure). A bug in a component ends the
    run with a RuntimeError that says how far it got; a component's ``FusionError`` (bad input the run
    cannot go on with) is raised as is, after the sinks are closed."""
    lines, name, close = _lines_of(source, label)
    session = Run(system, sinks, on_event=on_event, progress=progress, plot=plot, hooks=hooks,
                  label=label if label is not None else name, on_truth=on_truth)
    interrupted = False
    source_error = component_error = None
    try:
        session.consume(iter_messages(_guarded(lines), session.parsed, raw_streams=COMPARED))
    except KeyboardInterrupt:
        interrupted = True
    except _SourceLost as exc:
        source_error = _source_message(name, exc.__cause__ or exc)
    except ProcessModelFailed as exc:
        component_error = str(exc)
    except FusionError:
        session.close_sinks()
        raise
    except Exception as exc:
        session.close_sinks()
        last = session.last
        where = f"t = {last.t:.3f} s" if last is not None and math.isfinite(last.t) else "the start"
        raise RuntimeError(f"{exc} (the run got as far as {where}, {session.stats.estimates} estimates)") from exc
    finally:
        if close is not None:
            close()
    try:
        return session.finish(flush=component_error is None, interrupted=interrupted, source_error=source_error,
                              component_error=component_error)
    except KeyboardInterrupt:  # a second Ctrl-C while flushing: report what there is
        return session.finish(flush=False, interrupted=True, source_error=source_error,
                              component_error=component_error)
