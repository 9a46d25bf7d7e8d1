"""The run loop's orchestrator (DESIGN.md "The run loop"): messages -> clock guard -> reorder buffer -> the input
integrator or the measurement step -> estimates and events, in one direction.

``Loop.run(messages)`` (or ``push`` one at a time, then ``finish``) is a generator of ``Estimate``, ``Event`` and
``Updated`` (an update's NIS, for the statistics) items; fusion.run.session drives it over a source and hands
what it yields to RunStats and the sinks. The loop works on its own deep copies of the system's stateful parts
(process model, filter, sensors with their solvers), so the wired ``System`` is never modified and two runs of
it give identical results; it keeps nothing that grows with the length of a run.

The parts: fusion.run.clock (stamps), .reorder (the window), .inputs (samples waiting), .integrator
(prediction), .measure (an update, as a function), .startup (the first belief), .replay (late_policy: replay),
.plan (each sensor's bound callables), .tally (what the filter did), .checks (what plugins hand back).
"""
from __future__ import annotations

import copy
import math
from typing import Iterable, Iterator

from fusion.api import Estimate, Event, MalformedMessage, Message, ReadsBelief, ReportsStepEvents, has
from fusion.config import System
from fusion.run.checks import Failures
from fusion.run.clock import COMPARED, ClockGuard
from fusion.run.integrator import Integrator
from fusion.run.measure import Updated
from fusion.run.plan import plan_sensor
from fusion.run.process import Processor
from fusion.run.reorder import ReorderBuffer
from fusion.run.replay import ReplayLog, replay_late
from fusion.run.startup import StartUp
from fusion.run.tally import Tally

__all__ = ["Loop", "Updated"]

BATCH_MAX = 64     # input samples integrated per predict_inputs call at most (bounds the live latency)
MAX_UNUSED = 100   # distinct unknown sensor names counted by name; more are counted under "(other)"


class Loop:
    """Runs a wired System over a stream of Messages (see the module)."""

    def __init__(self, system: System):
        self.system = system
        spec = system.spec
        # one deepcopy call, so objects shared between components stay shared
        self.process, self.filter, self.sensors = copy.deepcopy((system.process, system.filter, system.sensors))
        self.max_latency = spec.scheduler.max_latency
        self.late_policy = spec.scheduler.late_policy
        # The cadence bound tells a wild stamp from a message that merely arrives early only by what its sensor
        # sends next, so it would take arrival jitter for wild stamps; a replaying loop expects jitter.
        cadence_k = spec.scheduler.cadence_k if self.late_policy != "replay" else 0.0
        self.clock = ClockGuard(spec.scheduler.future_s, spec.scheduler.resync_after,
                                max_gap_s=spec.scheduler.max_predict_s, cadence_k=cadence_k,
                                cadence_floor_s=spec.scheduler.cadence_floor_s, window_s=self.max_latency,
                                sensors=self.sensors, hold_start=True)
        self.max_predict = spec.scheduler.max_predict_s
        self.on_update = spec.output.on_update
        self.plans = {n: plan_sensor(s, spec.initial.align_s) for n, s in self.sensors.items()}
        self.tally = Tally(self.process.step_events if has(self.process, ReportsStepEvents) else None)
        self.failures = Failures(system.registry)
        pseudo = [(p, p.pseudo) for p in self.plans.values() if p.pseudo is not None]
        self.integrator = Integrator(system, self.filter, self.process, self.tally, pseudo, self.failures,
                                     batch=self.late_policy != "replay")
        self.startup = StartUp(system, self.filter, self.process, [n for n, p in self.plans.items() if p.aligns],
                               self.sensors, self.tally)
        self.buffer = ReorderBuffer(self.max_latency)
        self.replay = ReplayLog(spec.scheduler.history) if self.late_policy == "replay" else None
        self.gates = {n: p.gate for n, p in self.plans.items() if p.gate is not None}
        self.processor = Processor(self)
        self.pending = self.processor.pending
        self.unused: dict[str, int] = {}
        self._full_told = False
        for sensor in self.sensors.values():   # preprocessors that read the belief (fusion.api.ReadsBelief)
            if isinstance(sensor.preprocessor, ReadsBelief):
                sensor.preprocessor.bind_belief(self.processor.belief_at)

    # ------------------------------------------------------------------ what the run reads
    @property
    def newest(self) -> float:
        """The latest sensor time (s) accepted so far (-inf before any)."""
        return self.buffer.newest

    @property
    def buffered(self) -> int:
        """Messages in the reorder buffer now."""
        return len(self.buffer)

    @property
    def filter_counters(self) -> dict[str, int]:
        return dict(self.tally.counters)

    @property
    def gate_counters(self) -> dict[str, dict[str, int]]:
        """Per gated sensor, its gate's decisions this run (``checked``, ``rejected``, reasons)."""
        return {n: dict(g.counters) for n, g in self.gates.items()}

    @property
    def steps(self) -> dict[str, int]:
        return self.tally.steps

    @property
    def time_s(self) -> dict[str, float]:
        return self.tally.time_s

    @property
    def update_failures(self) -> dict[tuple[str, str], list]:
        """Per (sensor, component): [messages lost to its failure, the first reason]."""
        return self.failures.by

    @property
    def alignment_not_static(self) -> str | None:
        return self.startup.alignment_not_static

    @property
    def belief(self):
        """The run's belief now (None before the start)."""
        return self.processor.belief

    @property
    def resets(self) -> int:
        """Recoveries from a lock-out (fusion.recovery) so far."""
        return self.processor.resets

    def start_without_fix(self, output_hz: float | None = None) -> None:
        """Start without waiting for ``initial.from_sensor`` (the recording has no such stream); ``output_hz``:
        estimates by prediction at that rate when the config has none (a run that may have no update)."""
        self.startup.start_without_fix()
        if output_hz and not self.integrator.output_dt:
            self.integrator.output_dt = 1.0 / output_hz

    # ------------------------------------------------------------------ feeding
    def run(self, messages: Iterable[Message | MalformedMessage]) -> Iterator[Estimate | Event]:
        """Consume messages (and malformed-line markers from fusion.logformat.iter_messages): the estimates and
        events (``push`` and ``finish`` yield the ``Updated`` records too)."""
        for item in messages:
            for out in self.push(item):
                if out.__class__ is not Updated:
                    yield out
        for out in self.finish():
            if out.__class__ is not Updated:
                yield out

    def push(self, item: Message | MalformedMessage) -> Iterable:
        """Accept one message; returns (an iterable of) what it releases. The common case, an input sample that
        only joins the pending ones, returns an empty tuple without building a generator."""
        if item.__class__ is Message:
            sensor = self.sensors.get(item.sensor)
            if sensor is not None:
                t, buffer = item.t, self.buffer
                if (sensor.role == "input" and self.integrator.batch and not sensor.time_offset and not buffer
                        and self.max_latency == 0.0 and t >= buffer.horizon and t < self.integrator.next_output
                        and not self.clock.busy and len(self.pending) < BATCH_MAX - 1
                        and self.clock.steady(item.sensor, t, buffer.newest)):
                    sensor.counters["received"] += 1
                    buffer.passed(t)
                    self.pending.add(item)
                    return ()
            elif item.sensor in COMPARED:
                return ()
        return self._push(item)

    def _push(self, item: Message | MalformedMessage) -> Iterator:
        if isinstance(item, MalformedMessage):
            name = getattr(item, "sensor", None)
            if name in self.sensors:   # a line the parser refused is still a message of that sensor
                counters = self.sensors[name].counters
                counters["received"] += 1
                counters["malformed"] += 1
            yield Event(math.nan, "malformed", name, f"line {getattr(item, 'lineno', '?')}: {item}")
            return
        sensor = self.sensors.get(item.sensor)
        if sensor is None:
            if item.sensor not in COMPARED:
                yield from self._unknown(item)
            return
        sensor.counters["received"] += 1
        admitted, events = self.clock.admit(sensor.name, item, item.t + sensor.time_offset, self.buffer.newest)
        if events:
            self._count_wild()
        yield from events
        for m, t in admitted:  # other sensors' held messages the stream reached come first
            yield from self._accept(m, t)

    def _unknown(self, msg: Message) -> Iterator[Event]:
        name = msg.sensor if msg.sensor in self.unused or len(self.unused) < MAX_UNUSED else "(other)"
        n = self.unused.get(name, 0)
        self.unused[name] = n + 1
        if n == 0:
            yield Event(msg.t, "warning", msg.sensor, f"sensor {msg.sensor!r} is not in the config; its messages are ignored")

    def _count_wild(self) -> None:
        """Held messages the clock guard dropped as wild stamps: malformed (their time is)."""
        for name, n in self.clock.take_dropped().items():
            if name in self.sensors:
                self.sensors[name].counters["malformed"] += n

    def _accept(self, msg: Message, t: float) -> Iterator:
        """A message on the stream's time base, stamped ``t`` (s, offsets applied)."""
        if t != msg.t:
            msg = Message(t, msg.sensor, msg.values, msg.line)
        buffer = self.buffer
        if buffer.late(t):
            if self.replay is None or not self.replay:
                self.sensors[msg.sensor].counters["late"] += 1
                yield Event(t, "late", msg.sensor, f"{buffer.horizon - t:.3f} s behind the released horizon; dropped")
                return
            # counted by its re-run outcome (late when it cannot be replayed)
            yield from replay_late(msg, self.replay, self.processor, self.on_update)
            return
        buffer.add(t, msg)
        yield from self._release(buffer.due)
        if buffer.overfull:   # a window longer than the buffer holds: the oldest go on early
            if not self._full_told:
                self._full_told = True
                yield Event(t, "warning", None, f"the reorder buffer holds {buffer.capacity} messages, fewer than "
                            f"scheduler.max_latency ({self.max_latency:g} s) spans: the oldest are released "
                            "early, and a message later older than them is late")
            while buffer.overfull:
                yield from self._release(buffer.oldest)

    def _release(self, until: float, flush: bool = True) -> Iterator:
        buffer, pending, batch = self.buffer, self.pending, self.integrator.batch
        while (msg := buffer.pop(until)) is not None:
            if batch and self.sensors[msg.sensor].role == "input":
                # input samples wait until the belief is needed (a measurement, an output tick, the end, or a
                # full run), then go to the filter in one predict_inputs call
                pending.add(msg)
                if len(pending) >= BATCH_MAX or msg.t >= self.integrator.next_output:
                    yield from self.processor.flush_inputs()
                continue
            yield from self.processor.process(msg)
        if until == math.inf and pending and flush:
            yield from self.processor.flush_inputs()

    def finish(self) -> Iterator:
        """Release everything still held (end of input)."""
        yield from self.clock.flush()
        self._count_wild()
        released = self.clock.release()
        self._count_wild()
        for m, t in released:  # held by the cadence bound, never contradicted
            yield from self._accept(m, t)
        yield from self._release(math.inf, flush=False)
        # what the preprocessors still gather comes before the last input samples are integrated, so a final
        # fix is not older than the belief
        processor = self.processor
        for sensor in self.sensors.values():
            if sensor.preprocessor is not None:
                outs, failure = processor.flushed(sensor)
                if failure is not None:      # a plugin's flush failed: named, its held messages lost
                    yield Event(math.nan, "warning", sensor.name, failure)
                sensor.counters["absorbed"] -= len(outs)     # fixes of messages it held (counted absorbed)
                yield from processor.take_deferred()
                for out in outs:
                    yield from processor.measure(sensor, out)
            yield from processor.drain(sensor.name)
        if self.pending:
            yield from processor.flush_inputs()
        yield from self.failures.warnings()
        if self.integrator.failed:
            yield Event(math.nan, "warning", None, f"process model {self.process.name!r}: {self.integrator.failed} "
                        "prediction(s) failed; the belief was held over each")

