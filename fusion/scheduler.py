"""Time alignment of asynchronous sensor messages; drives predict/update; emits estimates (DESIGN.md).

Messages go through a reorder buffer of ``max_latency`` seconds (sensor time, after each sensor's
``time_offset``) and are released in time order. Input samples (role ``input``, the IMU) are integrated
into the prediction in order, the last sample held over the interval to the next time; measurements
are fused by updates at their own times; outputs are emitted at each update and/or at a fixed rate.

A message older than the released horizon is late: ``drop`` counts it, ``replay`` rewinds to the newest
stored belief before it and re-runs the processed messages after it (bounded history).

``Scheduler.run(messages)`` is a generator of ``Estimate`` and ``Event`` objects, so a live UI can
consume it as it goes. The one loop that drives a scheduler over a source is ``fusion.pipeline``.

A scheduler works on its own deep copies of the system's stateful parts (process model, filter, sensors
with their solvers, gates and counters), so the wired ``System`` is never modified and two runs of it
give identical results. It keeps nothing that grows with the length of a run: the NIS of each update
goes to ``on_nis`` (the pipeline's statistics), truth and reference lines are the pipeline's, not fed here.
"""
from __future__ import annotations

import bisect
import copy
import heapq
import itertools
import math
import time
from collections import Counter, deque
from dataclasses import dataclass
from typing import Callable, Iterable, Iterator

import numpy as np

from fusion.api import (Aligns, AlignsState, Belief, ChecksGeometry, Estimate, Event, HasThreshold, MalformedMessage,
                        Message, PositionFromFix, PredictsInputRuns, PseudoMeasurement, ReadsBelief, RejectedMessage,
                        UpdateResult, UsesInput, has)
from fusion.clock import ClockGuard
from fusion.recovery import LockoutWatch, recover
from fusion.config import SensorRuntime, System


@dataclass
class _Snapshot:
    t: float
    belief: Belief
    u: np.ndarray | None
    next_output: float
    index: int  # position in the processed-message log after which this snapshot was taken


_NOT_FED = frozenset(("truth", "reference"))  # streams that are compared against, never fused
_CHECK_EVERY_S = 0.5  # a model's check() (geometry) runs at most this often per sensor, s of sensor time
_BATCH_MAX = 64  # input samples integrated per predict_inputs call at most (bounds the live latency)


def _failed(component, exc: Exception) -> MalformedMessage:
    """A plugin's unexpected exception on one message, as the reason that message is malformed (the
    plugin should raise MalformedMessage itself; the run goes on either way)."""
    who = f"{component.kind} {component.name!r}" if component is not None else "a plugin"
    return MalformedMessage(f"{who} failed on it: {type(exc).__name__}: {exc}")


def _msg_t(msg: Message) -> float:
    return msg.t


class Scheduler:
    """Runs a wired System over a stream of Messages."""

    MAX_UNUSED = 100  # distinct unknown sensor names counted by name; more are counted under "(other)"

    def __init__(self, system: System, on_nis: Callable[[str, float, float, int, bool], None] | None = None):
        self.system = system
        # Private copies: components keep diagnostics (counters, a solver's open cycle); the System stays
        # as wired (one deepcopy call, so objects shared between components stay shared).
        self.process, self.filter, self.sensors = copy.deepcopy((system.process, system.filter, system.sensors))
        self.on_nis = on_nis  # called (sensor, t, nis, dim, accepted) after every update tried
        spec = system.spec
        self.max_latency = spec.scheduler.max_latency
        self.late_policy = spec.scheduler.late_policy
        self.clock = ClockGuard(spec.scheduler.future_s, spec.scheduler.resync_after, on_drop=self._count_wild,
                                max_gap_s=spec.scheduler.max_predict_s)
        self._future = spec.scheduler.future_s
        self.max_predict = spec.scheduler.max_predict_s
        self.output_dt = 1.0 / spec.output.rate_hz if spec.output.rate_hz else None
        self.on_update = spec.output.on_update
        self.belief: Belief | None = None
        self.u: np.ndarray | None = None
        self._buffer: list[tuple[float, int, Message]] = []
        self._seq = itertools.count()
        self._newest = -math.inf
        self._horizon = -math.inf
        self._next_output = math.inf
        self._history: deque[_Snapshot] = deque(maxlen=spec.scheduler.history)
        self._log: deque[Message] = deque(maxlen=spec.scheduler.history * 8)
        self._log_start = 0
        self._replaying = False
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
        self._pending: list[Message] = []
        self._warned: set[str] = set()  # sensors whose model's check() currently warns
        self._checked: dict[str, float] = {}  # sensor time of each sensor's last check()
        # Initialisation: x0/P0 refined by a fix of initial.from_sensor and/or alignment over a static start.
        self._x0 = system.x0.copy()
        self._P0 = system.P0.copy()
        self._align_s = spec.initial.align_s
        self._from_sensor = spec.initial.from_sensor
        self._have_fix = self._from_sensor is None
        self._align_u: list[np.ndarray] = []
        self._align_t0: float | None = None
        self._last_input_t: float | None = None
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
        if self._pseudo:
            self._batch = False

    # ------------------------------------------------------------------ public
    def run(self, messages: Iterable[Message | MalformedMessage]) -> Iterator[Estimate | Event]:
        """Consume messages (and malformed-line markers from fusion.logformat.iter_messages)."""
        for item in messages:
            yield from self.push(item)
        yield from self.finish()

    def push(self, item: Message | MalformedMessage) -> Iterable[Estimate | Event]:
        """Accept one message; returns (an iterable of) whatever it releases. Iterate it to drive the filter.

        The common cases (a truth line; an input sample that only joins the pending batch) return an empty
        tuple without building a generator: at 100-200 Hz that is a measurable share of a replay."""
        if item.__class__ is Message:
            sensor = self.sensors.get(item.sensor)
            if sensor is not None:
                t = item.t
                if (sensor.role == "input" and self._batch and not sensor.time_offset and not self._buffer
                        and self.max_latency == 0.0 and t >= self._horizon and t < self._next_output
                        and t <= self._newest + self._future and not self.clock.busy
                        and len(self._pending) < _BATCH_MAX - 1):
                    sensor.counters["received"] += 1
                    self._horizon = self._newest = t
                    self._pending.append(item)
                    return ()
            elif item.sensor in _NOT_FED:
                return ()
        return self._push(item)

    def _push(self, item: Message | MalformedMessage) -> Iterator[Estimate | Event]:
        if isinstance(item, MalformedMessage):
            sensor = getattr(item, "sensor", None)
            if sensor in self.sensors:
                self.sensors[sensor].counters["malformed"] += 1
            yield Event(math.nan, "malformed", sensor, f"line {getattr(item, 'lineno', '?')}: {item}")
            return
        msg = item
        sensor = self.sensors.get(msg.sensor)
        if sensor is None:
            if msg.sensor in _NOT_FED:
                return
            name = msg.sensor if msg.sensor in self.unused or len(self.unused) < self.MAX_UNUSED else "(other)"
            n = self.unused.get(name, 0)
            self.unused[name] = n + 1
            if n == 0:
                yield Event(msg.t, "warning", msg.sensor, f"sensor {msg.sensor!r} is not in the config; its messages are ignored")
            return
        sensor.counters["received"] += 1
        admitted, events = self.clock.admit(sensor.name, msg, msg.t + sensor.time_offset, self._newest)
        yield from events
        for m, t in admitted:
            yield from self._accept(sensor, m, t)

    def _count_wild(self, sensor: str, n: int) -> None:
        """Held messages the clock guard dropped as wild stamps: malformed (their time is)."""
        if sensor in self.sensors:
            self.sensors[sensor].counters["malformed"] += n

    def _accept(self, sensor: SensorRuntime, msg: Message, t: float) -> Iterator[Estimate | Event]:
        """A message on the stream's time base, stamped ``t`` (s, offsets applied)."""
        if t != msg.t:
            msg = Message(t, msg.sensor, msg.values, msg.line)
        if t < self._horizon:
            if self.late_policy == "drop" or not self._history:
                sensor.counters["late"] += 1
                yield Event(t, "late", msg.sensor, f"{self._horizon - t:.3f} s behind the released horizon; dropped")
                return
            sensor.counters["late"] += 1
            yield from self._replay(msg)
            return
        heapq.heappush(self._buffer, (t, next(self._seq), msg))
        self._newest = max(self._newest, t)
        yield from self._release(self._newest - self.max_latency)

    def finish(self) -> Iterator[Estimate | Event]:
        """Release everything still buffered (end of input)."""
        yield from self.clock.flush()
        yield from self._release(math.inf, flush=False)
        # What the preprocessors still gather comes before the last input samples are integrated, so a
        # final fix is not older than the belief.
        for sensor in self.sensors.values():
            if sensor.preprocessor is not None:
                outs = sensor.preprocessor.flush()
                if self._deferred:
                    deferred, self._deferred = self._deferred, []
                    yield from deferred
                for out in outs:
                    yield from self._measure(sensor, out)
                yield from self._drain_solver_events(sensor)
        if self._pending:
            yield from self._flush_inputs()

    # ------------------------------------------------------------------ internals
    def _release(self, until: float, flush: bool = True) -> Iterator[Estimate | Event]:
        pending = self._pending
        while self._buffer and self._buffer[0][0] <= until:
            _, _, msg = heapq.heappop(self._buffer)
            if msg.t > self._horizon:
                self._horizon = msg.t
            if self._batch and self.sensors[msg.sensor].role == "input":
                # Input samples wait until the belief is needed (a measurement, an output tick, the end, or
                # a full batch), then go to the filter in one predict_inputs call.
                pending.append(msg)
                if len(pending) >= _BATCH_MAX or msg.t >= self._next_output:
                    yield from self._flush_inputs()
                continue
            # Pending inputs stay pending through measurements that produce no observation (ranges a
            # solver gathers); _measure flushes them, up to its own time, when it needs the belief.
            yield from self._process(msg)
        if until == math.inf and pending and flush:
            yield from self._flush_inputs()

    def _flush_inputs(self, until: float | None = None) -> Iterator[Estimate | Event]:
        """Integrate the pending input samples; with ``until`` only those up to that time (the last one held
        to it), the later ones stay pending, so a measurement at ``until`` is applied at its own time."""
        pending = self._pending
        if until is not None and pending and pending[-1].t > until:
            k = bisect.bisect_right(pending, until, key=_msg_t)      # pending is in time order
            batch, self._pending = pending[:k], pending[k:]
            if not batch:
                return
        else:
            batch, self._pending = pending, []
        if batch:  # nothing pending: nothing to integrate (a measurement right after a flush)
            yield from self._inputs(batch, until)

    def _process(self, msg: Message) -> Iterator[Estimate | Event]:
        if not self._replaying:
            self._record(msg)
        sensor = self.sensors[msg.sensor]
        if sensor.role == "input":
            yield from self._inputs([msg])
            return
        users = self._input_users.get(msg.sensor)
        if users or (self.belief is None and msg.sensor in self._aligners):
            # integrate the inputs up to this message first: a UsesInput component reads the latest sample,
            # and an aligning sensor's message must know whether the static start is over
            if self._pending:
                yield from self._flush_inputs(until=msg.t if self.belief is not None else None)
            for c in users or ():
                c.take_input(self._last_input_t, self._last_u)
        try:
            decoded = sensor.decoder.decode(msg)
            if decoded is None:
                return
            outs = [decoded] if sensor.preprocessor is None else sensor.preprocessor.feed(decoded)
        except MalformedMessage as exc:
            yield self._bad(sensor, msg, exc)
            return
        except Exception as exc:  # a plugin that fails on one message must not stop the run
            yield self._bad(sensor, msg, _failed(sensor.preprocessor or sensor.decoder, exc))
            return
        if self._deferred:                      # what a belief_at() call released (outputs, input events)
            deferred, self._deferred = self._deferred, []
            yield from deferred
        yield from self._drain_solver_events(sensor)
        for out in outs:
            yield from self._measure(sensor, out)
        self._snapshot()

    def _check(self, sensor: SensorRuntime, model) -> Iterator[Event]:
        """A model's ChecksGeometry capability (e.g. the range model's geometry warning), reported when a
        warning starts and when it clears, not at every update."""
        if not has(model, ChecksGeometry):
            return
        check = model.check
        t = self.belief.t  # type: ignore[union-attr]
        if t - self._checked.get(sensor.name, -math.inf) < _CHECK_EVERY_S:
            return
        self._checked[sensor.name] = t
        events = check(self.belief, sensor.name)
        active = sensor.name in self._warned
        if events and not active:
            self._warned.add(sensor.name)
            yield from events
        elif not events and active:
            self._warned.discard(sensor.name)
            yield Event(self.belief.t, "cleared", sensor.name, "the geometry warning no longer applies")  # type: ignore[union-attr]

    @staticmethod
    def _bad(sensor: SensorRuntime, msg: Message, exc: MalformedMessage) -> Event:
        """Count a message a plugin refused (rejected: outside the sensor's limits; else malformed)."""
        kind = "rejected" if isinstance(exc, RejectedMessage) else "malformed"
        sensor.counters[kind] += 1
        return Event(msg.t, kind, sensor.name, f"line {msg.line}: {exc}")

    def _drain_solver_events(self, sensor: SensorRuntime) -> Iterator[Event]:
        """The events a preprocessor (fusion.api.Solver) appended to its ``events`` since the last call."""
        pre = sensor.preprocessor
        if pre is None:
            return
        events = pre.take_events()
        if events:
            yield from events

    def _belief_at(self, t: float) -> Belief | None:
        """The belief predicted to ``t`` with the inputs so far (for a ReadsBelief preprocessor), or None before
        initialisation; later than ``t`` when inputs past it are already integrated. What the prediction
        emits is yielded after the preprocessor's feed returns."""
        if self.belief is None:
            return None
        if self._pending:
            self._deferred.extend(self._flush_inputs(until=t))
        if self.belief.t < t:
            self._deferred.extend(self._predict_to(t))
        return self.belief

    def _start(self, t: float) -> None:
        """The first belief, at ``t``: the configured one, aligned and with the remembered fix if any."""
        self.belief = self.filter.initial_belief(t, *self._initial())
        self._next_output = t + self.output_dt if self.output_dt else math.inf

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

    def _take_filter_events(self) -> list[Event]:
        events, self._filter_events = self._filter_events, []
        return [] if self._replaying else events

    def _predicted(self, belief: Belief, k: int, batched: bool = False) -> Belief:
        """Count a prediction of ``k`` samples; the events the filter put on the belief are kept for the event
        stream and counted, and dropped from the belief the run goes on with."""
        self.steps["predict"] += k
        fc = self.filter_counters
        fc["predicts"] += k
        if batched:
            fc["batched_predicts"] += 1
        if belief.events:
            for e in belief.events:
                fc[e.kind] += 1
            self._filter_events.extend(belief.events)
            belief = belief.with_(events=())
        return belief

    def _tally(self, result: UpdateResult) -> None:
        """Count an update's outcome and keep the events it reported for the event stream."""
        fc = self.filter_counters
        if result.accepted:
            fc["updates"] += 1
            if result.iterations:
                fc["update_iterations"] += result.iterations
        else:
            fc["rejected"] += 1
        if result.events:
            for e in result.events:
                fc[e.kind] += 1
            self._filter_events.extend(result.events)

    def _step(self, t: float) -> None:
        dt = t - self.belief.t  # type: ignore[union-attr]
        if dt <= 0.0:
            return
        if self.process.input_dim and self.u is None:
            # No input sample yet: nothing to propagate with; hold the belief, move its time.
            self.belief = self.belief.with_(t=t)  # type: ignore[union-attr]
            return
        t0 = time.perf_counter()
        belief = self.filter.predict(self.belief, self.process, self.u, dt)
        self.time_s["predict"] += time.perf_counter() - t0
        self.belief = self._predicted(belief, 1)
        if self._pseudo:
            self._pseudo_updates()

    def _pseudo_updates(self) -> None:
        """The after-predict pseudo-measurements (fusion.api.PseudoMeasurement), in config order."""
        for sensor in self._pseudo:
            obs = sensor.model.pseudo_observation(self.belief)  # type: ignore[union-attr]
            if obs is None:
                continue
            R = obs.R if obs.R is not None else sensor.R
            result = self.filter.update(self.belief, obs.model, obs.z, R, sensor.gate)
            self._tally(result)
            if result.accepted:
                self.belief = result.belief
                sensor.counters["used"] += 1
            else:
                sensor.counters["rejected"] += 1

    def _inputs(self, msgs: list[Message], until: float | None = None) -> Iterator[Estimate | Event]:
        """Integrate input samples in order (the held sample propagates up to each new sample time);
        with ``until``, the last sample is held up to that time in the same batch."""
        sensor = self.sensors[msgs[0].sensor]
        good: list[tuple[float, np.ndarray]] = []
        for msg in msgs:
            try:
                decoded = sensor.decoder.decode(msg)
                if decoded is None:
                    continue
                u = self.process.input_from(decoded)
            except MalformedMessage as exc:
                yield self._bad(sensor, msg, exc)
                continue
            except Exception as exc:  # a plugin that fails on one message must not stop the run
                yield self._bad(sensor, msg, _failed(sensor.decoder, exc))
                continue
            if sensor.max_gap is not None and self._last_input_t is not None and msg.t - self._last_input_t > sensor.max_gap:
                yield Event(msg.t, "gap", msg.sensor, f"no {msg.sensor} sample for {msg.t - self._last_input_t:.3f} s "
                            f"(limit {sensor.max_gap} s); prediction held the last sample")
            self._last_input_t = msg.t
            good.append((msg.t, u))
        if good:
            self._last_u = good[-1][1]
        if self.belief is None:
            good = self._align(good, sensor)
        if not good:
            return
        end = until if until is not None and until >= good[-1][0] else None
        last_t = good[-1][0] if end is None else end
        if self._batch and (len(good) > 1 or end is not None) and self.u is not None and self._next_output > last_t:
            # Whole run of samples in one call (the filter integrates them in order, DESIGN: same math).
            ts = np.array([self.belief.t] + [t for t, _ in good] + ([end] if end is not None else []))  # type: ignore[union-attr]
            us = np.vstack([self.u] + [u for _, u in (good if end is not None else good[:-1])])
            dts = np.diff(ts)
            capped = dts.max() > self.max_predict
            if capped:
                yield Event(float(ts[-1]), "gap", sensor.name, f"{dts.max():.3f} s between input samples; "
                            f"prediction bounded to {self.max_predict:g} s (scheduler.max_predict_s)")
                np.minimum(dts, self.max_predict, out=dts)
            keep = dts > 0
            if keep.any():
                t0 = time.perf_counter()
                k = int(keep.sum())
                belief = self.filter.predict_inputs(self.belief, self.process, us[keep], dts[keep])
                self.time_s["predict"] += time.perf_counter() - t0
                self.belief = self._predicted(belief, k, batched=k > 1)
                if capped:  # bounded gap: the run still ends at the last sample's time
                    self.belief = self.belief.with_(t=last_t)
                if self._filter_events:
                    yield from self._take_filter_events()
            self.u = good[-1][1]
            sensor.counters["used"] += len(good)
        else:
            for t, u in good:
                yield from self._predict_to(t)
                self.u = u
                sensor.counters["used"] += 1
        self._snapshot()

    def _align(self, good: list[tuple[float, np.ndarray]], sensor: SensorRuntime) -> list[tuple[float, np.ndarray]]:
        """Before the first belief: gather the static start; create the belief once aligned (and fixed).
        Returns the samples left to integrate after the belief exists."""
        for i, (t, u) in enumerate(good):
            if self._align_t0 is None:
                self._align_t0 = t
            if t - self._align_t0 < self._align_s or not self._have_fix:
                self._align_u.append(u)
                sensor.counters["used"] += 1
                continue
            if self._align_s and self._align_u:
                u_mean = np.mean(self._align_u, axis=0)
                if has(self.process, Aligns):   # wiring refuses align_s for a process without it
                    self._x0, self._P0 = self.process.align(self._x0, self._P0, u_mean)
                for name, observations in self._aligners.items():
                    if observations:
                        s = self.sensors[name]
                        self._x0, self._P0 = s.model.align_state(self._x0, self._P0, u_mean, observations, s.R)  # type: ignore[union-attr]
            self._start(t)
            self.u = u
            sensor.counters["used"] += 1
            return good[i + 1:]
        return []

    def _measure(self, sensor: SensorRuntime, msg: Message) -> Iterator[Estimate | Event]:
        try:
            obs = sensor.model.observe(msg)  # type: ignore[union-attr]
        except MalformedMessage as exc:
            yield self._bad(sensor, msg, exc)
            return
        except Exception as exc:  # a plugin that fails on one message must not stop the run
            yield self._bad(sensor, msg, _failed(sensor.model, exc))
            return
        if obs is None:
            return
        if self._pending:
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
        result = self.filter.update(self.belief, obs.model, obs.z, R, sensor.gate)
        self.time_s["update"] += time.perf_counter() - t0
        self.steps["update"] += 1
        self._tally(result)
        watch = self._watch.get(sensor.name)
        if watch is not None and not self._replaying:
            threshold = self._thresholds.get(sensor.name)
            th = threshold(len(obs.z)) if threshold is not None else None
            if watch.update(obs.t, result.accepted, result.nis, th):
                watch.clear()
                self.resets += 1
                self.belief, event = recover(sensor.recovery, self.belief, self.system.layout, obs, R,  # type: ignore[arg-type]
                                             self.filter, sensor.name)
                yield event
                result = self.filter.update(self.belief, obs.model, obs.z, R, sensor.gate)
                self.steps["update"] += 1
                self._tally(result)
        if self._filter_events:
            yield from self._take_filter_events()
        if result.accepted:
            sensor.counters["used"] += 1
            self.belief = result.belief
            if not self._replaying:
                yield from self._check(sensor, obs.model)
        else:
            sensor.counters["rejected"] += 1
            if not self._replaying:
                yield Event(obs.t, "rejected", sensor.name, f"NIS {result.nis:.1f} outside the gate")
        if not self._replaying:
            if self.on_nis is not None:
                self.on_nis(sensor.name, obs.t, result.nis, len(obs.z), result.accepted)
            if self.on_update:
                yield Estimate(obs.t, self.belief, "update", sensor.name, result)

    def _take_fix(self, obs) -> None:
        """Remember a fix of ``initial.from_sensor`` for the initial position (latest fix wins)."""
        self._fix = obs
        self._have_fix = True

    def _initial(self) -> tuple[np.ndarray, np.ndarray]:
        """x0, P0 with the position block from the remembered fix. A model with ``position_from`` (a
        position with a lever arm) turns the fix into the state's position at the initial attitude."""
        x0, P0 = self._x0.copy(), self._P0.copy()
        obs = getattr(self, "_fix", None)
        if obs is None:
            return x0, P0
        sl = self.system.layout["p"]
        m = len(obs.z)
        to_state = obs.model.position_from if has(obs.model, PositionFromFix) else None
        x0[sl.start:sl.start + m] = to_state(obs.z, x0)[:m] if to_state else obs.z
        if obs.R is not None:
            idx = np.arange(sl.start, sl.start + m)
            P0[idx, :] = 0.0
            P0[:, idx] = 0.0
            P0[np.ix_(idx, idx)] = obs.R
        return x0, P0

    # ------------------------------------------------------------------ replay
    def _record(self, msg: Message) -> None:
        if self.late_policy != "replay":
            return
        if len(self._log) == self._log.maxlen:
            self._log_start += 1
        self._log.append(msg)

    def _snapshot(self) -> None:
        if self.late_policy != "replay" or self._replaying or self.belief is None:
            return
        self._history.append(_Snapshot(self.belief.t, self.belief, self.u, self._next_output,
                                       self._log_start + len(self._log)))

    def _replay(self, late: Message) -> Iterator[Estimate | Event]:
        snap = None
        for s in reversed(self._history):
            if s.t <= late.t and s.index >= self._log_start:
                snap = s
                break
        sensor = self.sensors[late.sensor]
        if snap is None:
            yield Event(late.t, "late", late.sensor, "older than the replay history; dropped")
            return
        rerun = list(itertools.islice(self._log, snap.index - self._log_start, None))
        rerun.append(late)
        rerun.sort(key=lambda m: m.t)
        self.belief, self.u, self._next_output = snap.belief, snap.u, snap.next_output
        self._replaying = True
        counters = {n: dict(s.counters) for n, s in self.sensors.items()}
        try:
            for msg in rerun:
                for out in self._process(msg):
                    pass
        finally:
            self._replaying = False
        for n, s in self.sensors.items():  # re-run messages were already counted
            s.counters.update(counters[n])
        sensor.counters["used"] += 1
        self._record(late)
        self._history.clear()
        self._snapshot()
        yield Event(late.t, "replayed", late.sensor, f"re-ran {len(rerun)} messages")
        if self.on_update and self.belief is not None:
            yield Estimate(self.belief.t, self.belief, "update", late.sensor)
