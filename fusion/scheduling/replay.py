"""The scheduler's ``late_policy: replay``: a bounded log of processed messages and snapshots of the
belief (with the gates' per-run states, values like the belief), and the rewind that re-runs the buffered
messages around a late one. A mixin of fusion.scheduler.Scheduler."""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any, Iterator

import numpy as np

from fusion.api import Belief, Estimate, Event, Message


@dataclass
class _Snapshot:
    t: float
    belief: Belief
    u: np.ndarray | None
    next_output: float
    index: int  # position in the processed-message log after which this snapshot was taken
    gates: dict[str, Any]  # sensor -> its gate's state (fusion.api.GateRun.state)
    gate_counts: dict[str, Any]  # sensor -> its gate's counters then: a replay re-counts from here
    u_t: float | None = None  # the time of the input sample u


class Replay:
    """Mixin: ``_record``, ``_snapshot``, ``_replay`` (see fusion.scheduler)."""

    def _record(self, msg: Message) -> None:
        if self.late_policy != "replay":
            return
        if len(self._log) == self._log.maxlen:
            self._log_start += 1
        self._log.append(msg)

    def _snapshot(self, rerun: bool = False) -> None:
        """Keep the belief (and the gates' states) after the messages logged so far; ``rerun``: also
        while a late message's re-run is in progress (its states are the run's from then on)."""
        if self.late_policy != "replay" or (self._replaying and not rerun) or self.belief is None:
            return
        self._history.append(_Snapshot(self.belief.t, self.belief, self.u, self._next_output,
                                       self._log_start + len(self._log),
                                       {n: g.state for n, g in self.gates.items()},
                                       {n: g.counters.copy() for n, g in self.gates.items()}, self._u_t))

    def _replay(self, late: Message) -> Iterator[Estimate | Event]:
        snap = None
        for s in reversed(self._history):
            if s.t <= late.t and s.index >= self._log_start:
                snap = s
                break
        sensor = self.sensors[late.sensor]
        if snap is None:
            sensor.counters["late"] += 1
            yield Event(late.t, "late", late.sensor, "older than the replay history; dropped")
            return
        keep = snap.index - self._log_start
        rerun = list(itertools.islice(self._log, keep, None))
        rerun.append(late)
        rerun.sort(key=lambda m: m.t)
        # The log from the snapshot on is rewritten in the order the re-run processes it, and the snapshots
        # after it (states the late message changes) give way to the re-run's own: the history stays valid
        # for the next late message, which may be older than this one's re-run (consecutive late ranges).
        while len(self._log) > keep:
            self._log.pop()
        while self._history and self._history[-1] is not snap:
            self._history.pop()
        self.belief, self.u, self._next_output, self._u_t = snap.belief, snap.u, snap.next_output, snap.u_t
        for n, state in snap.gates.items():
            # the gate decides the re-run messages again, and its counts are those of the re-run decisions
            # (the late message's included), not the ones made before the late message arrived
            self.gates[n].state = state
            self.gates[n].counters = snap.gate_counts[n].copy()
        self._replaying = True
        counters = {n: dict(s.counters) for n, s in self.sensors.items()}
        own: dict[str, int] = {}      # the late message's own outcome in the re-run (used, rejected, ...)
        events: list[Event] = []      # and what it reported (a rejection, a geometry warning)
        try:
            for msg in rerun:
                self._record(msg)
                if msg is late:
                    # the late message is new to the run: its outcome, events and NIS are reported as in
                    # time order (self._live); the others were already, before it arrived
                    before = dict(sensor.counters)
                    self._live = True
                    try:
                        events += [e for e in self._process(msg) if isinstance(e, Event)]
                    finally:
                        self._live = False
                    own = {k: v - before.get(k, 0) for k, v in sensor.counters.items() if v != before.get(k, 0)}
                else:
                    for out in self._process(msg):
                        pass
                if self.sensors[msg.sensor].role != "input":   # as a run keeps them: after measurements
                    self._snapshot(rerun=True)
        finally:
            self._replaying = False
            self._live = False
        for n, s in self.sensors.items():  # re-run messages were already counted
            s.counters.update(counters[n])
        # Counted once, by its re-run outcome, not as late (received = used + rejected + malformed + late +
        # absorbed; its "replayed" event says it came late).
        for k, v in own.items():
            sensor.counters[k] += v
        self._snapshot()
        yield from events
        yield Event(late.t, "replayed", late.sensor, f"re-ran {len(rerun)} messages")
        if self.on_update and self.belief is not None:
            yield Estimate(self.belief.t, self.belief, "update", late.sensor)
