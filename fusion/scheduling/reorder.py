"""The scheduler's reorder buffer: messages on the stream's time base (each sensor's ``time_offset``
applied, the clock guard's verdict), held ``max_latency`` seconds and released in time order; input
samples gathered into runs for the filter's PredictsInputRuns capability; late messages dropped or
replayed. A mixin of fusion.scheduler.Scheduler."""
from __future__ import annotations

import math
from typing import Iterable, Iterator

from fusion.api import Estimate, Event, MalformedMessage, Message
from fusion.config import SensorRuntime

_NOT_FED = frozenset(("truth", "reference"))  # streams that are compared against, never fused
_BATCH_MAX = 64  # input samples integrated per predict_inputs call at most (bounds the live latency)


class Reordering:
    """Mixin: ``push``, ``_push``, ``_accept``, ``_release``, ``_flush_inputs`` (see fusion.scheduler)."""

    @property
    def newest(self) -> float:
        """The latest sensor time (s) accepted so far (-inf before any): where the clock guard centres
        its window for truth and reference lines as for the sensors."""
        return self.buffer.newest

    @property
    def buffered(self) -> int:
        """Messages in the reorder buffer now (at most BUFFER_MAX)."""
        return len(self.buffer)

    def push(self, item: Message | MalformedMessage) -> Iterable[Estimate | Event]:
        """Accept one message; returns (an iterable of) whatever it releases. Iterate it to drive the filter.

        The common cases (a truth line; an input sample that only joins the pending batch) return an empty
        tuple without building a generator: at 100-200 Hz that is a measurable share of a replay."""
        if item.__class__ is Message:
            sensor = self.sensors.get(item.sensor)
            if sensor is not None:
                t = item.t
                buffer = self.buffer
                if (sensor.role == "input" and self._batch and not sensor.time_offset and not buffer
                        and self.max_latency == 0.0 and t >= buffer.horizon and t < self._next_output
                        and not self.clock.busy and len(self.pending) < _BATCH_MAX - 1
                        and self.clock.steady(item.sensor, t, buffer.newest)):
                    sensor.counters["received"] += 1
                    buffer.passed(t)
                    self.pending.add(item)
                    return ()
            elif item.sensor in _NOT_FED:
                return ()
        return self._push(item)

    def _push(self, item: Message | MalformedMessage) -> Iterator[Estimate | Event]:
        if isinstance(item, MalformedMessage):
            sensor = getattr(item, "sensor", None)
            if sensor in self.sensors:
                # a line the parser refused is still a message of that sensor (received = used + rejected +
                # malformed + late + absorbed holds for it)
                counters = self.sensors[sensor].counters
                counters["received"] += 1
                counters["malformed"] += 1
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
        admitted, events = self.clock.admit(sensor.name, msg, msg.t + sensor.time_offset, self.buffer.newest)
        if events:
            self._count_wild()
        yield from events
        for m, t in admitted:  # other sensors' held messages the stream reached come first
            yield from self._accept(sensor if m.sensor == msg.sensor else self.sensors[m.sensor], m, t)

    def _accept(self, sensor: SensorRuntime, msg: Message, t: float) -> Iterator[Estimate | Event]:
        """A message on the stream's time base, stamped ``t`` (s, offsets applied)."""
        if t != msg.t:
            msg = Message(t, msg.sensor, msg.values, msg.line)
        buffer = self.buffer
        if buffer.late(t):
            if self.late_policy == "drop" or not self._history:
                sensor.counters["late"] += 1
                yield Event(t, "late", msg.sensor, f"{buffer.horizon - t:.3f} s behind the released horizon; dropped")
                return
            yield from self._replay(msg)    # counted by its re-run outcome (late when it cannot be replayed)
            return
        buffer.add(t, msg)
        yield from self._release(buffer.due)
        if buffer.overfull:
            # a window longer than the buffer holds: the oldest go on early (the horizon with them)
            if not self._buffer_full_told:
                self._buffer_full_told = True
                yield Event(t, "warning", None, f"the reorder buffer holds {buffer.capacity} messages, fewer than "
                            f"scheduler.max_latency ({self.max_latency:g} s) spans: the oldest are released "
                            "early, and a message later older than them is late")
            while buffer.overfull:
                yield from self._release(buffer.oldest)

    def _release(self, until: float, flush: bool = True) -> Iterator[Estimate | Event]:
        buffer = self.buffer
        while (msg := buffer.pop(until)) is not None:
            if self._batch and self.sensors[msg.sensor].role == "input":
                # Input samples wait until the belief is needed (a measurement, an output tick, the end, or
                # a full batch), then go to the filter in one predict_inputs call.
                pending = self.pending
                pending.add(msg)
                if len(pending) >= _BATCH_MAX or msg.t >= self._next_output:
                    yield from self._flush_inputs()
                continue
            # Pending inputs stay pending through measurements that produce no observation (ranges a
            # solver gathers); _measure flushes them, up to its own time, when it needs the belief.
            yield from self._process(msg)
        if until == math.inf and self.pending and flush:
            yield from self._flush_inputs()

    def _flush_inputs(self, until: float | None = None) -> Iterator[Estimate | Event]:
        """Integrate the pending input samples; with ``until`` only those up to that time (the last one held
        to it), the later ones stay pending, so a measurement at ``until`` is applied at its own time."""
        batch = self.pending.take(until)
        if batch:  # nothing pending: nothing to integrate (a measurement right after a flush)
            yield from self._inputs(batch, until)
