"""Time alignment of asynchronous sensor messages; drives predict/update; emits estimates (DESIGN.md).

Messages go through a reorder buffer of ``max_latency`` seconds (sensor time, after each sensor's
``time_offset``) and are released in time order. Input samples (role ``input``, the IMU) are integrated
into the prediction in order, the last sample held over the interval to the next time; measurements
are fused by updates at their own times; outputs are emitted at each update and/or at a fixed rate.

A message older than the released horizon is late: ``drop`` counts it, ``replay`` rewinds to the newest
stored belief before it and re-runs the processed messages after it (bounded history); a replayed message
is counted once, by what its re-run made of it (used, rejected, ...), with its events and NIS, and late only
when it is older than the history.

Modules: this one is the loop (processing, prediction, updates); fusion.scheduling holds the reorder
buffer (``reorder``), the initialisation (``initialisation``), what is counted and reported
(``reporting``) and ``late_policy: replay`` (``replay``), as mixins of :class:`Scheduler`.

``Scheduler.run(messages)`` is a generator of ``Estimate`` and ``Event`` objects, so a live UI can
consume it as it goes. The one loop that drives a scheduler over a source is ``fusion.pipeline``.

A scheduler works on its own deep copies of the system's stateful parts (process model, filter, sensors
with their solvers, gates and counters), so the wired ``System`` is never modified and two runs of it
give identical results. It keeps nothing that grows with the length of a run: the NIS of each update
goes to ``on_nis`` (the pipeline's statistics), truth and reference lines are the pipeline's, not fed here.
"""
from __future__ import annotations

import copy
import itertools
import math
import time
from collections import Counter, deque
from typing import Callable, Iterable, Iterator

import numpy as np

from fusion.api import (AlignsState, Belief, Estimate, Event, Fix, FusionError, HasThreshold, HoldsInput,
                        MalformedMessage, Message, PredictsInputRuns, PseudoMeasurement, ReadsBelief, UsesInput, has)
from fusion.run.clock import ClockGuard
from fusion.errors import ModelFault
from fusion.recovery import LockoutWatch, recover
from fusion.config import SensorRuntime, System
from fusion.scheduling.checks import CheckedGateRun, GateFailed, shown, usable, who as _who
from fusion.scheduling.initialisation import FIXES_MAX, Initialisation
from fusion.run.inputs import PendingInputs
from fusion.run.reorder import ReorderBuffer
from fusion.scheduling.reorder import Reordering
from fusion.scheduling.replay import Replay, _Snapshot
from fusion.scheduling.reporting import Reporting


def _failed(component, exc: Exception, registry=None) -> MalformedMessage:
    """A plugin's unexpected exception on one message, as the reason that message is malformed (the
    plugin should raise MalformedMessage itself; the run goes on either way)."""
    return MalformedMessage(f"{_who(component, registry)} failed on it: {type(exc).__name__}: {exc}")


class ProcessModelFailed(FusionError):
    """The process model (or the filter's prediction with it) raised on every prediction of
    :data:`PREDICT_FAILS_MAX` in a row: the belief cannot be carried on, so the run stops there (``fusion run``:
    exit 2, the summary of what was processed written)."""


#: Predictions in a row that may fail (each holds the belief over its step, the first reported) before the run
#: stops with ProcessModelFailed: one odd input sample is not the end of a run, a process model that always
#: raises is.
PREDICT_FAILS_MAX = 5


class Scheduler(Reordering, Initialisation, Reporting, Replay):
    """Runs a wired System over a stream of Messages."""

    MAX_UNUSED = 100  # distinct unknown sensor names counted by name; more are counted under "(other)"

    def __init__(self, system: System, on_nis: Callable[[str, float, float, int, bool], None] | None = None):
        self.system = system
        # Private copies: components keep diagnostics (counters, a solver's open cycle); the System stays
        # as wired (one deepcopy call, so objects shared between components stay shared).
        self.process, self.filter, self.sensors = copy.deepcopy((system.process, system.filter, system.sensors))
        # Per sensor, the components that queue events for the run (a Solver's ``events``; a decoder's or
        # model's own ``take_events``: the nmea decoder's moving start, an alignment without magnetometer)
        self._drainers = {n: [c.take_events for c in (s.preprocessor, s.decoder, s.model)
                              if c is not None and callable(getattr(c, "take_events", None))]
                          for n, s in self.sensors.items()}
        self.on_nis = on_nis  # called (sensor, t, nis, dim, accepted) after every update tried
        spec = system.spec
        self.max_latency = spec.scheduler.max_latency
        self.late_policy = spec.scheduler.late_policy
        # The cadence bound tells a wild stamp from a message that merely arrives early only by what its
        # sensor sends next, so it would take arrival jitter for wild stamps; a replaying scheduler expects
        # jitter (it rewinds for late messages), so the bound is off there.
        cadence_k = spec.scheduler.cadence_k if self.late_policy != "replay" else 0.0
        self.clock = ClockGuard(spec.scheduler.future_s, spec.scheduler.resync_after,
                                max_gap_s=spec.scheduler.max_predict_s, cadence_k=cadence_k,
                                cadence_floor_s=spec.scheduler.cadence_floor_s, window_s=self.max_latency,
                                sensors=self.sensors, hold_start=True)
        self.max_predict = spec.scheduler.max_predict_s
        self.output_dt = 1.0 / spec.output.rate_hz if spec.output.rate_hz else None
        self.on_update = spec.output.on_update
        self.belief: Belief | None = None
        self.u: np.ndarray | None = None
        self.buffer = ReorderBuffer(self.max_latency)
        self._buffer_full_told = False
        self._next_output = math.inf
        self._history: deque[_Snapshot] = deque(maxlen=spec.scheduler.history)
        self._log: deque[Message] = deque(maxlen=spec.scheduler.history * 8)
        self._log_start = 0
        self._replaying = False
        self._live = False   # in a replay's re-run, processing the late message itself (its outcome is new)
        # Plugin failures on a measurement (a model's h or jacobian raising in the update, a gate's check, an
        # unusable Observation): per (sensor, component) [count, first reason] of messages lost; and the
        # predictions that failed in a row.
        self._update_failures: dict[tuple[str, str], list] = {}
        self._predict_fails = 0
        self._predict_failures = 0
        self.steps = {"predict": 0, "update": 0}
        # What the filter returned, counted here (filters keep no counters): predicts, batched_predicts (runs
        # of input samples given in one predict_inputs call), updates, rejected, update_iterations, and the
        # kinds of the events it reported (not_positive_definite).
        self.filter_counters: Counter = Counter()
        self._filter_events: list[Event] = []   # reported by the filter inside a prediction, not yet yielded
        self.time_s = {"predict": 0.0, "update": 0.0}
        self.unused: dict[str, int] = {}
        self._watch = {n: LockoutWatch(s.recovery) for n, s in self.sensors.items() if s.recovery is not None}
        self.resets = 0
        # Batched input integration (filter.predict_inputs) needs no per-sample replay log.
        self._batch = has(self.filter, PredictsInputRuns) and self.late_policy != "replay"
        # An input gap cut into several predictions by the other sensors: each is told how long the sample
        # it holds has been held already (fusion.api.HoldsInput), so the gap is one hold, not many.
        self._hold_after = self.process.hold_after if has(self.process, HoldsInput) else None
        self.pending = PendingInputs()
        self._warned: set[str] = set()  # sensors whose model's check() currently warns
        self._checked: dict[str, float] = {}  # sensor time of each sensor's last check()
        # Initialisation: x0/P0 refined by a fix of initial.from_sensor and/or alignment over a static start.
        self._x0 = system.x0.copy()
        self._P0 = system.P0.copy()
        self._align_s = spec.initial.align_s
        self._from_sensor = spec.initial.from_sensor
        self._have_fix = self._from_sensor is None
        self._align_u: list[np.ndarray] = []
        self._align_t: list[float] = []
        self._align_t0: float | None = None
        # The fixes of initial.from_sensor before the start, and the window's verdict (ChecksStillness: True
        # static, False moving, None not judged): a static window's fixes are combined (initialisation.py).
        self._fixes: deque = deque(maxlen=FIXES_MAX)
        self._still: bool | None = None
        self.alignment_not_static: str | None = None   # why the window was judged moving (summary health)
        self._last_input_t: float | None = None
        self._u_t: float | None = None   # the time of the sample in self.u (how long it has been held)
        # The input sensor whose silence is reported while the other sensors go on (its max_gap)
        gaps = [(n, s.max_gap) for n, s in self.sensors.items() if s.role == "input" and s.max_gap is not None]
        self._input_gap = gaps[0] if gaps else None
        self._silence_told = False
        self._silence_last = -math.inf   # the input's last sample time when its silence was told
        # Preprocessors that read the belief (fusion.api.ReadsBelief), bound once here.
        self._deferred: list[Estimate | Event] = []
        for sensor in self.sensors.values():
            if isinstance(sensor.preprocessor, ReadsBelief):
                sensor.preprocessor.bind_belief(self._belief_at)
        # Optional capabilities (fusion.api), detected once: models that align part of the state from their
        # static observations, components that read the input at their messages, after-predict pseudo-
        # measurements (these integrate inputs one by one, so the rule holds for every sample).
        self._aligners: dict[str, list] = {n: [] for n, s in self.sensors.items()
                                           if self._align_s and isinstance(s.model, AlignsState)}
        self._input_users = {n: [c for c in (s.preprocessor, s.model) if isinstance(c, UsesInput)]
                             for n, s in self.sensors.items()}
        self._input_users = {n: c for n, c in self._input_users.items() if c}
        self._last_u: np.ndarray | None = None
        self._pseudo = [s for s in self.sensors.values()
                        if isinstance(s.model, PseudoMeasurement) and s.model.rule == "after_predict"]
        self._thresholds = {n: s.gate.threshold for n, s in self.sensors.items() if has(s.gate, HasThreshold)}
        # The gates' per-run state and decision counts (fusion.api.GateRun), what the filter's update is given.
        self.gates = {n: CheckedGateRun(s.gate) for n, s in self.sensors.items() if s.gate is not None}
        if self._pseudo:
            self._batch = False

    # ------------------------------------------------------------------ public
    def run(self, messages: Iterable[Message | MalformedMessage]) -> Iterator[Estimate | Event]:
        """Consume messages (and malformed-line markers from fusion.logformat.iter_messages)."""
        for item in messages:
            yield from self.push(item)
        yield from self.finish()

    def finish(self) -> Iterator[Estimate | Event]:
        """Release everything still buffered (end of input)."""
        yield from self.clock.flush()
        self._count_wild()
        released = self.clock.release()
        self._count_wild()
        for m, t in released:  # held by the cadence bound, never contradicted
            yield from self._accept(self.sensors[m.sensor], m, t)
        yield from self._release(math.inf, flush=False)
        # What the preprocessors still gather comes before the last input samples are integrated, so a
        # final fix is not older than the belief.
        for sensor in self.sensors.values():
            if sensor.preprocessor is not None:
                outs = self._flushed(sensor)
                if outs is None:                            # a plugin's flush failed: named, its held messages lost
                    yield Event(math.nan, "warning", sensor.name, self._flush_failure)
                    outs = ()
                sensor.counters["absorbed"] -= len(outs)     # fixes of messages it held (counted absorbed)
                if self._deferred:
                    deferred, self._deferred = self._deferred, []
                    yield from deferred
                for out in outs:
                    yield from self._measure(sensor, out)
            yield from self._drain_solver_events(sensor)
        if self.pending:
            yield from self._flush_inputs()
        for (name, _), (n, why) in self._update_failures.items():
            if n > 1:
                yield Event(math.nan, "warning", name, f"{why} {n} times, each message lost (counted malformed)")
        if self._predict_failures:
            yield Event(math.nan, "warning", None, f"process model {self.process.name!r}: {self._predict_failures} "
                        "prediction(s) failed; the belief was held over each")

    # ------------------------------------------------------------------ internals

    def _flushed(self, sensor: SensorRuntime) -> list | tuple | None:
        """The preprocessor's ``flush()`` at the end of the input, checked as its ``feed`` is (a list or tuple
        of Message or Fix); None, with the reason in ``_flush_failure``, when it raised or returned anything
        else: the end of a run is no place for a plugin's error to lose the summary."""
        pre = sensor.preprocessor
        try:
            outs = pre.flush()
        except Exception as exc:  # a plugin's failure at the end must not stop the run's end
            self._flush_failure = (f"{_who(pre, self.system.registry)} flush failed: {type(exc).__name__}: {exc}; "
                                   "the messages it held are lost")
            return None
        if type(outs) not in (list, tuple) or not all(isinstance(o, (Message, Fix)) for o in outs):
            self._flush_failure = (f"{_who(pre, self.system.registry)} flush returned {shown(outs)}, expected a "
                                   "list of fusion.api.Message or Fix; the messages it held are lost")
            return None
        return outs

    def _input_silence(self, t: float, other: str) -> Iterator[Event]:
        """One ``gap`` event when the input sensor has been silent for more than its max_gap at ``t`` (s), the
        time of another sensor's message: a sensor that dies is reported while the others go on, not only
        when (if ever) it comes back."""
        name, max_gap = self._input_gap  # type: ignore[misc]
        last = self.pending.last_t if self.pending else self._last_input_t
        if last is not None and t - last > max_gap:
            self._silence_told, self._silence_last = True, last
            yield Event(t, "gap", name, f"no {name} sample for {t - last:.3f} s (limit {max_gap} s) while {other} goes on; the "
                        "prediction holds the last sample")

    def _process(self, msg: Message) -> Iterator[Estimate | Event]:
        if not self._replaying:
            self._record(msg)
        sensor = self.sensors[msg.sensor]
        if sensor.role == "input":
            yield from self._inputs([msg])
            return
        if self._input_gap is not None and not self._silence_told:
            yield from self._input_silence(msg.t, msg.sensor)
        users = self._input_users.get(msg.sensor)
        if users or (self.belief is None and msg.sensor in self._aligners):
            # integrate the inputs up to this message first: a UsesInput component reads the latest sample,
            # and an aligning sensor's message must know whether the static start is over
            if self.pending:
                yield from self._flush_inputs(until=msg.t if self.belief is not None else None)
            for c in users or ():
                c.take_input(self._last_input_t, self._last_u)
        try:
            decoded = sensor.decoder.decode(msg)
            if decoded is None:
                sensor.counters["absorbed"] += 1     # the decoder dropped it (fusion.run_stats.ABSORBED)
                return
            if type(decoded) is not Message and not isinstance(decoded, Message):
                raise MalformedMessage(f"{_who(sensor.decoder, self.system.registry)} returned {shown(decoded)}, "
                                       "expected a fusion.api.Message or None")
            if sensor.preprocessor is None:
                outs = [decoded]
            else:                                    # held for a fix, or combined into the fix(es) it emits
                outs = sensor.preprocessor.feed(decoded)
                if type(outs) not in (list, tuple) or not all(isinstance(o, (Message, Fix)) for o in outs):
                    raise MalformedMessage(f"{_who(sensor.preprocessor, self.system.registry)} feed returned "
                                           f"{shown(outs)}, expected a list of fusion.api.Message or Fix")
                sensor.counters["absorbed"] += 1 - len(outs)
        except MalformedMessage as exc:
            yield self._bad(sensor, msg, exc)
            return
        except Exception as exc:  # a plugin that fails on one message must not stop the run
            yield self._bad(sensor, msg, _failed(sensor.preprocessor or sensor.decoder, exc, self.system.registry))
            return
        if self._deferred:                      # what a belief_at() call released (outputs, input events)
            deferred, self._deferred = self._deferred, []
            yield from deferred
        yield from self._drain_solver_events(sensor)
        for out in outs:
            yield from self._measure(sensor, out)
        self._snapshot()

    def _belief_at(self, t: float) -> Belief | None:
        """The belief predicted to ``t`` with the inputs so far (for a ReadsBelief preprocessor), or None before
        initialisation; later than ``t`` when inputs past it are already integrated. What the prediction
        emits is yielded after the preprocessor's feed returns."""
        if self.belief is None:
            return None
        if self.pending:
            self._deferred.extend(self._flush_inputs(until=t))
        if self.belief.t < t:
            self._deferred.extend(self._predict_to(t))
        return self.belief

    def _predict_to(self, t: float) -> Iterator[Estimate | Event]:
        """Predict with the held input up to ``t``, emitting fixed-rate outputs on the way. A gap longer
        than ``max_predict_s`` is bounded: the belief is predicted over the last ``max_predict_s`` of it
        only (its uncertainty grows as over that time, not without bound) and a ``gap`` event says so."""
        assert self.belief is not None
        gap = t - self.belief.t
        if gap > self.max_predict:
            yield Event(t, "gap", None, f"{gap:.3f} s without a message; prediction bounded to the last "
                        f"{self.max_predict:g} s (scheduler.max_predict_s)")
            self.belief = self.belief.with_(t=t - self.max_predict)
            if self.output_dt:
                k = math.ceil((self.belief.t - self._next_output) / self.output_dt)
                if k > 0:
                    self._next_output += k * self.output_dt
        while self._next_output <= t:
            self._step(self._next_output)
            if self._filter_events:
                yield from self._take_filter_events()
            if not self._replaying:
                yield Estimate(self.belief.t, self.belief, "output")
            self._next_output += self.output_dt  # type: ignore[operator]
        self._step(t)
        if self._filter_events:
            yield from self._take_filter_events()

    def _step(self, t: float) -> None:
        dt = t - self.belief.t  # type: ignore[union-attr]
        if dt <= 0.0:
            return
        if self.process.input_dim and self.u is None:
            # No input sample yet: nothing to propagate with; hold the belief, move its time.
            self.belief = self.belief.with_(t=t)  # type: ignore[union-attr]
            return
        t0 = time.perf_counter()
        process = self.process
        if self._hold_after is not None and self._u_t is not None:
            age = self.belief.t - self._u_t  # type: ignore[union-attr,operator]
            if age > 0.0 and age + dt > self._hold_after:
                process = process.held(age)  # type: ignore[attr-defined]
        try:
            belief = self.filter.predict(self.belief, process, self.u, dt)
        except FusionError:
            raise
        except Exception as exc:  # a process model's f or Q that raises: see _predict_failed
            self._predict_failed(exc, t, self.u, dt)
            return
        self._predict_fails = 0
        self.time_s["predict"] += time.perf_counter() - t0
        self.belief = self._predicted(belief, 1, dts=dt)
        if self._pseudo:
            self._pseudo_updates()

    def _predict_failed(self, exc: Exception, t: float, u: np.ndarray | None, dt: float) -> None:
        """A prediction to ``t`` raised. When the process model's own ``f`` or ``Q`` raises at the belief (input
        ``u``, step ``dt`` s), the belief is held over the step (moved to ``t`` unchanged), the first failure is
        reported, and :data:`PREDICT_FAILS_MAX` in a row stop the run with ProcessModelFailed, which names the
        process model. So does a ModelFault (the filter found a value the model returned unusable: the wrong
        shape, NaN, a Q not positive semi-definite). Otherwise it is the filter's own bug: ``exc`` is raised
        again (an internal error)."""
        if not isinstance(exc, ModelFault):
            x = _read_only(self.belief.x)  # type: ignore[union-attr]
            try:
                self.process.f(x, u, dt)
                self.process.Q(x, u, dt)
                self.process.jacobian(x, u, dt)
            except Exception as own:
                exc = own
            else:
                raise exc
        self._predict_fails += 1
        self._predict_failures += 1
        what = str(exc) if isinstance(exc, ModelFault) else f"{type(exc).__name__}: {exc}"
        why = f"process model {self.process.name!r} failed in a prediction: {what}"
        if self._predict_fails >= PREDICT_FAILS_MAX:
            raise ProcessModelFailed(f"{why} ({self._predict_fails} predictions in a row, at t = {t:.3f} s); the "
                                     "belief cannot be carried on") from exc
        if self._predict_failures == 1:
            self._filter_events.append(Event(t, "warning", None, f"{why}; the belief is held over the step"))
        self.belief = self.belief.with_(t=t)  # type: ignore[union-attr]

    def _update_failed(self, sensor: SensorRuntime, model, msg: Message, exc: Exception) -> Event | None:
        """An update of ``sensor`` raised. When its gate is at fault (GateFailed: its ``check`` raised or
        returned no ``(GateDecision, state)``) or its model is (its ``h`` or ``jacobian`` raises at the belief, or
        ``h`` returns another shape than ``(dim,)``), the message is lost (:meth:`_lost`: counted malformed, the
        belief kept, the first failure of each sensor and component reported naming it and the exception, the
        others counted, their number told at the end). Otherwise it is the filter's own bug: ``exc`` is raised
        again (an internal error)."""
        if isinstance(exc, GateFailed):
            who = _who(exc.gate, self.system.registry)
            return self._lost(sensor, msg, who, f"failed in the update: {exc}", f"failed in an update ({exc})")
        error = str(exc) if isinstance(exc, ModelFault) else _model_fault(model, _read_only(self.belief.x))  # type: ignore[union-attr]
        if error is None:
            raise exc
        who = _who(model, self.system.registry, "measurement model")
        return self._lost(sensor, msg, who, f"failed in the update: {error}", f"failed in an update ({error})")

    def _lost(self, sensor: SensorRuntime, msg: Message | Fix, who: str, what: str, short: str) -> Event | None:
        """A message of ``sensor`` lost to a plugin's failure on it (``who`` failed: ``what``): counted
        malformed; the first of each sensor and component is reported, the others counted and their number
        told at the end (``who short N times``)."""
        sensor.counters["malformed"] += 1
        if self._replaying and not self._live:   # a re-run message: counted and told when it first ran
            return None
        failures = self._update_failures.get((sensor.name, who))
        if failures is not None:
            failures[0] += 1
            return None
        self._update_failures[(sensor.name, who)] = [1, f"{who} {short}"]
        return Event(msg.t, "malformed", sensor.name, f"line {msg.line}: {who} {what}; the message is lost, the belief "
                     f"kept (further failures of {sensor.name} are counted)")

    def _pseudo_updates(self) -> None:
        """The after-predict pseudo-measurements (fusion.api.PseudoMeasurement), in config order."""
        for sensor in self._pseudo:
            obs = sensor.model.pseudo_observation(self.belief)  # type: ignore[union-attr]
            if obs is None:
                continue
            checked = usable(obs)
            if type(checked) is str:
                who = _who(sensor.model, self.system.registry, "measurement model")
                event = self._lost(sensor, Message(self.belief.t, sensor.name, (), "-"), who,  # type: ignore[union-attr]
                                   f"returned an unusable pseudo-observation: {checked}",
                                   f"returned an unusable pseudo-observation ({checked})")
                if event is not None:
                    self._filter_events.append(event)
                continue
            obs = checked
            R = obs.R if obs.R is not None else sensor.R
            try:
                result = self.filter.update(self.belief, obs.model, obs.z, R, self.gates.get(sensor.name))
            except FusionError:
                raise
            except Exception as exc:
                event = self._update_failed(sensor, obs.model, Message(self.belief.t, sensor.name, (), "-"), exc)
                if event is not None:
                    self._filter_events.append(event)
                continue
            self._tally(result)
            if result.accepted and _finite(result.nis, result.belief):
                self.belief = result.belief
                sensor.counters["used"] += 1
            else:
                sensor.counters["rejected"] += 1

    def _inputs(self, msgs: list[Message], until: float | None = None) -> Iterator[Estimate | Event]:
        """Integrate input samples in order (the held sample propagates up to each new sample time);
        with ``until``, the last sample is held up to that time in the same batch."""
        sensor = self.sensors[msgs[0].sensor]
        good: list[tuple[float, np.ndarray]] = []
        decode, input_from, max_gap = sensor.decoder.decode, self.process.input_from, sensor.max_gap  # per sample
        for msg in msgs:
            try:
                decoded = decode(msg)
                if decoded is None:
                    sensor.counters["absorbed"] += 1
                    continue
                u = input_from(decoded)
            except MalformedMessage as exc:
                yield self._bad(sensor, msg, exc)
                continue
            except Exception as exc:  # a plugin that fails on one message must not stop the run
                yield self._bad(sensor, msg, _failed(sensor.decoder, exc))
                continue
            t = msg.t
            last = self._last_input_t
            if max_gap is not None and last is not None and t - last > max_gap:
                if self._silence_told and t > self._silence_last:   # told while the others went on: it ends
                    yield Event(t, "resumed", msg.sensor, f"{msg.sensor} samples again after {t - last:.3f} s; "
                                "prediction held the last sample")
                else:                                               # one gap, one "gap" event
                    yield Event(t, "gap", msg.sensor, f"no {msg.sensor} sample for {t - last:.3f} s (limit "
                                f"{max_gap} s); prediction held the last sample")
            self._last_input_t = t
            if self._silence_told and t > self._silence_last:   # a new sample, not a held one
                self._silence_told = False
            good.append((t, u))
        if good:
            self._last_u = good[-1][1]
        if self.belief is None:
            good = self._align(good, sensor)
            if self.belief is not None:              # aligned now: what the aligning models said about it
                for name in self._aligners:
                    yield from self._drain_solver_events(self.sensors[name])
        if not good:
            return
        end = until if until is not None and until >= good[-1][0] else None
        last_t = good[-1][0] if end is None else end
        if (self._hold_after is not None and self._u_t is not None and self.belief is not None
                and self.belief.t > self._u_t and good[0][0] - self._u_t > self._hold_after):  # type: ignore[union-attr]
            # the end of an input gap the other sensors cut into predictions: its last stretch is one more
            # prediction of the held sample at its age (_step), not a fresh hold in the run below
            yield from self._predict_to(good[0][0])
        if self._batch and (len(good) > 1 or end is not None) and self.u is not None and self._next_output > last_t:
            # Whole run of samples in one call (the filter integrates them in order, DESIGN: same math).
            # The intervals as floats (the same subtractions np.diff makes), the arrays built once for the
            # samples kept (a zero interval, a repeated stamp, integrates nothing)
            ts = [self.belief.t] + [t for t, _ in good] + ([end] if end is not None else [])  # type: ignore[union-attr]
            ul = [self.u] + [u for _, u in (good if end is not None else good[:-1])]
            dl = [b - a for a, b in zip(ts, ts[1:])]
            top = max(dl)
            capped = top > self.max_predict
            if capped:
                yield Event(float(ts[-1]), "gap", sensor.name, f"{top:.3f} s between input samples; "
                            f"prediction bounded to {self.max_predict:g} s (scheduler.max_predict_s)")
                dl = [d if d <= self.max_predict else self.max_predict for d in dl]
            if not all(d > 0 for d in dl):
                ul = [u for u, d in zip(ul, dl) if d > 0]
                dl = [d for d in dl if d > 0]
            if dl:
                t0 = time.perf_counter()
                k = len(dl)
                us, dts = np.array(ul, dtype=float), np.array(dl, dtype=float)
                try:
                    belief = self.filter.predict_inputs(self.belief, self.process, us, dts)
                except FusionError:
                    raise
                except Exception as exc:   # as in _step: held over the run of samples
                    self._predict_failed(exc, last_t, us[0], float(dts[0]))
                    belief = None
                if belief is not None:
                    self._predict_fails = 0
                    self.time_s["predict"] += time.perf_counter() - t0
                    self.belief = self._predicted(belief, k, batched=k > 1, dts=dts)
                    if capped:  # bounded gap: the run still ends at the last sample's time
                        self.belief = self.belief.with_(t=last_t)
                if self._filter_events:
                    yield from self._take_filter_events()
            self.u, self._u_t = good[-1][1], good[-1][0]
            sensor.counters["used"] += len(good)
        else:
            for t, u in good:
                yield from self._predict_to(t)
                self.u, self._u_t = u, t
                sensor.counters["used"] += 1
        self._snapshot()

    def _measure(self, sensor: SensorRuntime, msg: Message) -> Iterator[Estimate | Event]:
        try:
            obs = sensor.model.observe(msg)  # type: ignore[union-attr]
        except MalformedMessage as exc:
            yield self._bad(sensor, msg, exc)
            return
        except Exception as exc:  # a plugin that fails on one message must not stop the run
            yield self._bad(sensor, msg, _failed(sensor.model, exc, self.system.registry))
            return
        if obs is None:
            sensor.counters["absorbed"] += 1
            return
        checked = usable(obs)
        if type(checked) is str:   # the model's bug (it should raise MalformedMessage): lose this message
            who = _who(sensor.model, self.system.registry, "measurement model")
            event = self._lost(sensor, msg, who, f"returned an unusable Observation: {checked}",
                               f"returned an unusable Observation ({checked})")
            if event is not None:
                yield event
            return
        obs = checked
        if self.pending:
            yield from self._flush_inputs(until=obs.t)
        if self.belief is None and self._from_sensor == sensor.name:
            self._take_fix(obs)
            sensor.counters["used"] += 1
            if not (self._align_s or self.process.input_dim):
                self._start(obs.t)
            return
        if self.belief is None and sensor.name in self._aligners:
            self._aligners[sensor.name].append(obs)          # static observations for its align_state
            sensor.counters["used"] += 1
            return
        if self.belief is None and (not self._have_fix or self.process.input_dim):
            sensor.counters["rejected"] += 1
            yield Event(obs.t, "rejected", sensor.name, "before the filter is initialised")
            return
        if self.belief is None:
            self._start(obs.t)
        if obs.t < self.belief.t:  # type: ignore[union-attr]
            # A fix stamped before the belief (e.g. a solver's cycle time): updating at the wrong time would
            # bias the estimate, so it is late like any other message.
            sensor.counters["late"] += 1
            yield Event(obs.t, "late", sensor.name, f"observation {self.belief.t - obs.t:.3f} s older than the "  # type: ignore[union-attr]
                        "belief; dropped (stamp fixes at the closing message)")
            return
        yield from self._predict_to(obs.t)
        R = obs.R if obs.R is not None else sensor.R
        if R is None:
            yield self._bad(sensor, msg, MalformedMessage(
                f"sensor {sensor.name!r} has no noise R in the config and its message carries none"))
            return
        if R.shape[0] != len(obs.z) and len(obs.z) % R.shape[0] == 0:
            R = np.kron(np.eye(len(obs.z) // R.shape[0]), R)  # R per item (a range) for a message of several
        t0 = time.perf_counter()
        # A model that initialises the state (``initialises``: the geometric solvers' initial fix) replaces an
        # uninformative prior: it is no measurement to test against that prior (a prior t 0 +- 1e5 s refused
        # the fix of a log stamped in Unix time, 1e6 s and more: tester3 #9)
        gate = None if getattr(obs.model, "initialises", False) else self.gates.get(sensor.name)
        try:
            result = self.filter.update(self.belief, obs.model, obs.z, R, gate)
        except FusionError:
            raise
        except Exception as exc:  # a model's h or jacobian that raises, or returns the wrong shape
            event = self._update_failed(sensor, obs.model, msg, exc)
            if event is not None:
                yield event
            return
        self.time_s["update"] += time.perf_counter() - t0
        self.steps["update"] += 1
        self._tally(result)
        watch = self._watch.get(sensor.name)
        if watch is not None and not self._replaying:
            threshold = self._thresholds.get(sensor.name)
            th = threshold(len(obs.z)) if threshold is not None else None
            if watch.update(obs.t, result.accepted, result.nis, th, result.innovation, result.S, obs.model):
                watch.clear()
                self.resets += 1
                self.belief, event = recover(sensor.recovery, self.belief, self.system.layout, obs, R,  # type: ignore[arg-type]
                                             self.filter, sensor.name)
                yield event
                try:
                    result = self.filter.update(self.belief, obs.model, obs.z, R, self.gates.get(sensor.name))
                except FusionError:
                    raise
                except Exception as exc:
                    event = self._update_failed(sensor, obs.model, msg, exc)
                    if event is not None:
                        yield event
                    return
                self.steps["update"] += 1
                self._tally(result)
        if self._filter_events:
            yield from self._take_filter_events()
        quiet = self._replaying and not self._live   # a re-run message: reported when it first ran
        if result.accepted and not _finite(result.nis, result.belief) and _finite(0.0, self.belief):
            # DESIGN: never a NaN propagated silently. A model whose prediction (or Jacobian) is not finite
            # at this state would make the belief NaN for the rest of the run, gate or no gate: refused.
            sensor.counters["rejected"] += 1
            if not quiet:
                yield Event(obs.t, "rejected", sensor.name, f"model {obs.model.name!r}: the update is not finite "
                            f"(NIS {result.nis}: its prediction or Jacobian at this state is NaN or inf); the "
                            "belief is kept")
            return
        if result.accepted:
            sensor.counters["used"] += 1
            self.belief = result.belief
            if not quiet:
                yield from self._check(sensor, obs.model)
        else:
            sensor.counters["rejected"] += 1
            if not quiet:
                yield Event(obs.t, "rejected", sensor.name, f"NIS {result.nis:.1f} outside the gate")
        if not quiet:
            if self.on_nis is not None:
                self.on_nis(sensor.name, obs.t, result.nis, len(obs.z), result.accepted)
            if self.on_update:
                yield Estimate(obs.t, self.belief, "update", sensor.name, result)


def _model_fault(model, x: np.ndarray) -> str | None:
    """Why a measurement model fails at the state ``x`` (n,) and on a batch of two (what a filter gives it): its
    ``h`` or ``jacobian`` raises (the exception), or ``h`` returns another shape than ``(dim,)`` / ``(2, dim)``;
    None when it does neither there (an update that failed anyway is the filter's bug)."""
    try:
        dim = int(model.dim)
        one, two = np.shape(model.h(x)), np.shape(model.h(np.stack([x, x])))
        if one != (dim,) or two != (2, dim):
            return f"h returned shape {one} at the belief ({two} on 2 states), expected ({dim},) ((2, {dim}))"
        model.jacobian(x)
    except Exception as exc:
        return f"{type(exc).__name__}: {exc}"
    return None


def _read_only(x: np.ndarray) -> np.ndarray:
    """A read-only view of the belief's mean for a model probed after a failure (one that writes into it raises)."""
    v = x.view()
    v.flags.writeable = False
    return v


def _finite(nis: float, belief: Belief | None) -> bool:
    """NIS, mean and covariance (or its factor) all finite (one sum each: ~1 us an update)."""
    if belief is None:
        return True
    m = belief.S if belief.S is not None else belief.P
    total = (0.0 if nis is None else float(nis)) + float(belief.x.sum()) + (float(m.sum()) if m is not None else 0.0)
    return total - total == 0.0
