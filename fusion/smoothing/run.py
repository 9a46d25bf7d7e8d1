"""A smoothed run: the forward pass through ``fusion.pipeline`` (recorded), then the backward pass.

    from fusion.smoothing import run_smoothed
    result = run_smoothed(system, system.recording, [sink])             # full RTS smoother
    result = run_smoothed(system, "-", [sink], lag=2.0)                 # fixed lag, 2 s late
    result.summary["errors"], result.summary["smoothed"]["errors"]    # filtered | smoothed

The sinks get the smoothed estimates (at the same times, reasons and sensors as the filter's), after
the forward pass (full) or ``lag`` s of sensor time late as the run goes (fixed lag). The summary is
the forward run's (its ``errors`` and ``consistency`` are the filtered ones) plus ``smoothed``: the
smoothed errors and NEES against the same truth, the wall time of the backward pass, the nodes and the
store. Memory: the forward pass writes its records to a :class:`fusion.smoothing.store.ChunkStore`
(on disk past its in-memory budget, ``disk``), and the fixed-lag smoother keeps only its window.
"""
from __future__ import annotations

import dataclasses
import time
from typing import Any, Callable, Sequence

from fusion.api import ConfigError, Estimate, Event, Message
from fusion.config import System
from fusion.metrics import ErrorTracker
from fusion.truth_stream import TruthComparison

from .backward import FixedLag, smooth, smoothed_estimates, state_difference
from .record import ForwardLog, RecordingFilter
from .store import ChunkStore

__all__ = ["run_smoothed", "smoother_backend", "input_max_hold"]


def smoother_backend(flt):
    """The Rauch-Tung-Striebel backend of a filter (``fusion_plugins.filters.rts.backend_for``)."""
    from fusion_plugins.filters.rts import backend_for

    return backend_for(flt)


def input_max_hold(system: System) -> float | None:
    """s: the longest an input sample may be held before the chain breaks (``ForwardLog.max_hold``):
    the input sensors' ``max_gap`` (the shortest, when several give one), None when none gives one."""
    gaps = [s.max_gap for s in system.sensors.values() if s.role == "input" and s.max_gap is not None]
    return min(gaps) if gaps else None


class _SmoothedStats:
    """Errors and NEES of the smoothed estimates against the run's truth (the forward run's settings)."""

    def __init__(self, system: System, names: Sequence[str] | None):
        ev = system.spec.evaluation
        self.tracker = ErrorTracker(system.layout, None, settle_s=ev.settle_s, position=ev.position,
                                    keep_nis_series=False)
        self.comparison = TruthComparison(self.tracker, names) if names else None
        self.started = False
        self.count = 0

    def add_truth(self, msg: Message) -> None:
        if self.comparison is not None:
            self.comparison.add_truth(msg)

    def add_estimate(self, est: Estimate) -> None:
        self.count += 1
        if not self.started:
            self.tracker.start(est.t)
            self.started = True
        if self.comparison is not None:
            self.comparison.add_estimate(est)

    def summary(self, system: System) -> dict[str, Any]:
        if self.comparison is not None:
            self.comparison.finish()
        s = self.tracker.summary()
        out: dict[str, Any] = {}
        if s.get("errors"):
            out["errors"] = s["errors"]
            if system.spec.evaluation.position:
                out["errors"]["position_elements"] = list(system.spec.evaluation.position)
        c = {k: v for k, v in (s.get("consistency") or {}).items() if k.startswith("nees")}
        if c:
            out["consistency"] = c
        return out


def _close(sinks: list) -> None:
    """Close the sinks once (as fusion.pipeline does, also when the run fails)."""
    while sinks:
        sinks.pop(0).close()


def _discard(sinks: list) -> None:
    """Drop what the sinks wrote (a file sink removes its temporary file: nothing appears under the final
    name); a sink without ``discard`` (a stream, a plugin's) is closed."""
    while sinks:
        sink = sinks.pop(0)
        getattr(sink, "discard", sink.close)()


#: The warning of a run interrupted after its input was read.
INTERRUPTED = ("interrupted after the input was read, while smoothing: the smoothed output is incomplete and was "
               "not written (a stream keeps what it got); the summary holds the forward run")


def _interrupted(result, sinks: list, smoother: str, written: int, on_event: Callable | None):
    """The forward run's result, marked interrupted, after Ctrl-C in the backward pass or while the
    smoothed estimates were written: the sinks are discarded, a warning says so."""
    _discard(sinks)
    detail = INTERRUPTED
    if on_event is not None:
        on_event(Event(float("nan"), "warning", None, detail))
    result.summary["interrupted"] = True
    result.summary["smoothed"] = {"smoother": smoother, "interrupted": detail, "estimates_written": written}
    return dataclasses.replace(result, interrupted=True)


def _backward(log: ForwardLog, fixed: FixedLag | None, lagged: ChunkStore | None, out: ChunkStore | None,
              sqrt: bool, normalize: Callable, diff: Callable, stats: _SmoothedStats, sinks: list) -> int:
    """The backward pass after the forward one: the full smoother into ``out`` (its estimates then go to the
    sinks), or the end of the fixed-lag window (already sent to the sinks as it went, kept in ``lagged``);
    the smoothed estimates and the recorded truth go to ``stats``. Returns the number of nodes."""
    if fixed is not None:
        fixed.finish()
        nodes = log.nodes + 1
        estimates = smoothed_estimates(lagged, sqrt, log.sensors, forward=True)  # type: ignore[arg-type]
    else:
        nodes = smooth(log, normalize, diff, out)
        estimates = smoothed_estimates(out, sqrt, log.sensors)
    truth = log.truth.forward_rows()
    pending = next(truth, None)
    for est in estimates:
        while pending is not None and pending["t"] <= est.t:
            stats.add_truth(Message(float(pending["t"]), "truth", tuple(pending["v"].tolist()), 0))
            pending = next(truth, None)
        stats.add_estimate(est)
        if fixed is None:
            for s in sinks:
                s.on_estimate(est)
    while pending is not None:
        stats.add_truth(Message(float(pending["t"]), "truth", tuple(pending["v"].tolist()), 0))
        pending = next(truth, None)
    return nodes


def run_smoothed(system: System, source: Any, sinks: Sequence[Any] = (), *, lag: float | None = None,
                 disk: bool | None = None, chunk: int = 1024, on_event: Callable | None = None,
                 progress: Callable | None = None, plot: Any = None, hooks: bool = True,
                 label: str | None = None, forward_sinks: Sequence[Any] = ()):
    """Run ``system`` over ``source`` and smooth (see the module). ``lag`` None: the full smoother;
    else the fixed-lag smoother with that lag (s). Returns the forward run's ``RunResult`` with the
    summary's ``smoothed`` section. ConfigError when the filter has no smoother or the scheduler
    replays late messages (the chain would fork). ``forward_sinks`` get the filtered estimates as the
    forward pass gives them (and are closed after it): filtered and smoothed from one run."""
    from fusion import pipeline

    if system.spec.scheduler.late_policy == "replay":
        raise ConfigError("smoothing needs scheduler.late_policy: drop (a replay rewinds the recorded chain)")
    if lag is not None and not lag >= 0.0:
        raise ConfigError(f"--smooth-lag must be a number of seconds >= 0, got {lag}")
    backend = smoother_backend(system.filter)
    process = system.process
    normalize, diff = process.normalize, state_difference(system.layout)
    sinks = list(sinks)
    fixed: FixedLag | None = None

    lagged = ChunkStore(chunk * 4, disk) if lag is not None else None

    def emit(est: Estimate) -> None:
        """A fixed-lag estimate: to the sinks now, to the store for the statistics after the run."""
        b = est.belief
        lagged.append(t=est.t, x=b.x, C=b.S if backend.sqrt else b.P,  # type: ignore[union-attr]
                      reason=ForwardLog.REASONS.index(est.reason), sensor=log.sensor_code(est.sensor))
        for s in sinks:
            s.on_estimate(est)

    if lag is not None:
        fixed = FixedLag(backend.sqrt, lag, normalize, diff, emit)
        log = ForwardLog(backend, system.layout.n, chunk, disk, on_step=fixed.on_step, keep=False,
                         max_hold=input_max_hold(system))
        fixed.log = log
    else:
        log = ForwardLog(backend, system.layout.n, chunk, disk, max_hold=input_max_hold(system))
    wrapped = dataclasses.replace(system, filter=RecordingFilter(system.filter, log))

    class _Forward:
        """The forward run's sink: notes estimates (and feeds the fixed-lag smoother)."""

        def on_estimate(self, est: Estimate) -> None:
            node = log.note_estimate(est)
            if fixed is not None and node is not None:
                fixed.on_estimate(est, node)
            for s in forward_sinks:
                s.on_estimate(est)

        def close(self) -> None:
            for s in forward_sinks:
                s.close()

    out: ChunkStore | None = None
    try:
        result = pipeline.run(wrapped, source, [_Forward()], on_event=on_event, progress=progress, plot=plot,
                              hooks=hooks, label=label, on_truth=log.note_truth)
        stats = _SmoothedStats(system, result.parsed.header.fields.get("truth"))
        out = ChunkStore(chunk * 4, disk) if fixed is None else None
        t0 = time.perf_counter()
        try:
            nodes = _backward(log, fixed, lagged, out, backend.sqrt, normalize, diff, stats, sinks)
        except KeyboardInterrupt:
            return _interrupted(result, sinks, "rts" if fixed is None else "fixed_lag", stats.count, on_event)
        backward_s = time.perf_counter() - t0
        _close(sinks)
        stores = [log.steps, log.estimates, log.truth] + [s for s in (out, lagged) if s is not None]
        smoothed = {"smoother": "rts" if fixed is None else "fixed_lag", "filter": system.filter.name,
                    **({"lag_s": lag} if lag is not None else {}),
                    **stats.summary(system),
                    "nodes": nodes, "estimates": stats.count, "breaks": log.breaks,
                    **({"input_gap_breaks": log.gap_breaks} if log.gap_breaks else {}),
                    **({"nonfinite_breaks": log.nonfinite_breaks} if log.nonfinite_breaks else {}),
                    "forward_wall_s": result.wall_s, "backward_wall_s": backward_s,
                    "store": {"on_disk": any(s.on_disk or s.bytes_on_disk for s in stores),
                              "bytes_on_disk": sum(s.bytes_on_disk for s in stores)}}
        if fixed is not None:
            smoothed["largest_window"] = fixed.largest_window
        if log.unmatched:
            smoothed["unmatched_estimates"] = log.unmatched
        result.summary["smoothed"] = smoothed
        return result
    except BaseException:
        _close(sinks)
        raise
    finally:
        log.close()
        for store in (out, lagged):
            if store is not None:
                store.close()
