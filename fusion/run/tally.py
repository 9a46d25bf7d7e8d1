"""What the run counts of its filter's work: predictions, updates and their outcomes, the events the filter (and
the process model, and the start-up) reported, kept in order until the loop hands them on. Filters keep no
counters: what they return is counted here."""
from __future__ import annotations

from collections import Counter
from typing import Callable

import numpy as np

from fusion.api import Belief, Event, UpdateResult

__all__ = ["Tally"]


class Tally:
    """``counters``: predicts, batched_predicts (runs of input samples given in one call), updates, rejected,
    update_iterations, and the kinds of the events reported (not_positive_definite, ...); ``steps``: predict
    and update steps; ``time_s``: s spent in each. ``step_events``: the process model's ReportsStepEvents
    (resolved once at wiring), or None."""

    __slots__ = ("counters", "steps", "time_s", "step_events", "_events")

    def __init__(self, step_events: Callable | None = None):
        self.counters: Counter = Counter()
        self.steps = {"predict": 0, "update": 0}
        self.time_s = {"predict": 0.0, "update": 0.0}
        self.step_events = step_events
        self._events: list[Event] = []

    def __bool__(self) -> bool:
        """Events wait to be handed on."""
        return bool(self._events)

    def add(self, event: Event) -> None:
        """An event of the run's own (a warning of the start-up or of a failed prediction), handed on in order
        with the filter's."""
        self._events.append(event)

    def take(self, quiet: bool = False) -> list[Event]:
        """The events kept so far, once (none when ``quiet``: a replay's re-run, told when it first ran)."""
        events, self._events = self._events, []
        return [] if quiet else events

    def reported(self, events) -> None:
        """Events a filter attached to a belief or result: counted by kind and kept."""
        fc = self.counters
        for e in events:
            fc[e.kind] += 1
        self._events.extend(events)

    def predicted(self, belief: Belief, k: int, batched: bool = False, dts=None) -> Belief:
        """Count a prediction of ``k`` samples (the process model's events over the sample intervals ``dts``, s,
        too); the events the filter put on the belief are kept, and dropped from the belief the run goes on
        with."""
        self.steps["predict"] += k
        fc = self.counters
        fc["predicts"] += k
        if batched:
            fc["batched_predicts"] += 1
        if dts is not None and self.step_events is not None:
            for e in self.step_events(belief.t, np.atleast_1d(dts)):
                fc[e.kind] += 1
                self._events.append(e)
        if belief.events:
            self.reported(belief.events)
            belief = belief.with_(events=())
        return belief

    def updated(self, result: UpdateResult) -> None:
        """Count an update's outcome and keep the events it reported."""
        fc = self.counters
        if result.accepted:
            fc["updates"] += 1
            if result.iterations:
                fc["update_iterations"] += result.iterations
        else:
            fc["rejected"] += 1
        if result.events:
            self.reported(result.events)
