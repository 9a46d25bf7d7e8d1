"""What the scheduler counts and reports: the filter's returned events and outcomes (filters keep no
counters), the gates' decisions (counted in the run's fusion.api.GateRun of each sensor: gates keep
nothing), a model's geometry warnings (ChecksGeometry), messages a plugin refused, a preprocessor's
events. A mixin of fusion.scheduler.Scheduler."""
from __future__ import annotations

import math
from typing import Iterator

import numpy as np

from fusion.api import (Belief, ChecksGeometry, Event, MalformedMessage, Message, RejectedMessage, ReportsStepEvents,
                        UpdateResult, has)
from fusion.config import SensorRuntime

_CHECK_EVERY_S = 0.5  # a model's check() (geometry) runs at most this often per sensor, s of sensor time


class Reporting:
    """Mixin: ``_predicted``, ``_tally``, ``_take_filter_events``, ``_check``, ``_bad``,
    ``_drain_solver_events``, ``_count_wild`` (see fusion.scheduler)."""

    @property
    def gate_counters(self) -> dict[str, dict[str, int]]:
        """Per gated sensor, its gate's decisions this run: ``checked``, ``rejected`` and the reasons the
        decisions gave (the ``reopening`` gate's ``opened``, ``closed``, ``accepted_open``)."""
        return {n: dict(g.counters) for n, g in self.gates.items()}

    def _take_filter_events(self) -> list[Event]:
        events, self._filter_events = self._filter_events, []
        return [] if self._replaying else events

    def _predicted(self, belief: Belief, k: int, batched: bool = False, dts=None) -> Belief:
        """Count a prediction of ``k`` samples; the events the filter put on the belief are kept for the event
        stream and counted, and dropped from the belief the run goes on with; so are the process model's
        events of the step (ReportsStepEvents, over the sample intervals ``dts``)."""
        self.steps["predict"] += k
        fc = self.filter_counters
        fc["predicts"] += k
        if batched:
            fc["batched_predicts"] += 1
        if dts is not None and has(self.process, ReportsStepEvents):
            for e in self.process.step_events(belief.t, np.atleast_1d(dts)):
                fc[e.kind] += 1
                self._filter_events.append(e)
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
        """The events the sensor's components queued since the last call: a preprocessor's (fusion.api.Solver
        ``events``), and a decoder's or model's that has ``take_events`` (Scheduler._drainers)."""
        for take in self._drainers.get(sensor.name, ()):
            events = take()
            if events:
                yield from events

    def _count_wild(self) -> None:
        """Held messages the clock guard dropped as wild stamps: malformed (their time is)."""
        for sensor, n in self.clock.take_dropped().items():
            if sensor in self.sensors:
                self.sensors[sensor].counters["malformed"] += n
