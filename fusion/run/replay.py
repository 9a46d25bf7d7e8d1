"""``late_policy: replay``: a bounded log of the messages processed and snapshots of the belief (with the gates'
per-run states, values like the belief), and the rewind that says what to re-run for a late message. The
re-run (:func:`replay_late`) goes through the run's Processor (fusion.run.process), given as an argument."""
from __future__ import annotations

import itertools
from collections import deque
from dataclasses import dataclass
from typing import Any, Iterator

import numpy as np

from fusion.api import Belief, Estimate, Event, Message

__all__ = ["Snapshot", "ReplayLog", "replay_late"]


@dataclass
class Snapshot:
    t: float
    belief: Belief
    u: np.ndarray | None
    next_output: float
    index: int  # position in the processed-message log after which this snapshot was taken
    gates: dict[str, Any]  # sensor -> its gate's state (fusion.api.GateRun.state)
    gate_counts: dict[str, Any]  # sensor -> its gate's counters then: a replay re-counts from here
    u_t: float | None = None  # the time of the input sample u


class ReplayLog:
    """The last ``history`` snapshots and ``8 x history`` processed messages."""

    def __init__(self, history: int):
        self._history: deque[Snapshot] = deque(maxlen=history)
        self._log: deque[Message] = deque(maxlen=history * 8)
        self._start = 0   # messages that fell off the log's start

    def __bool__(self) -> bool:
        """Some snapshot is kept (a late message may be replayable)."""
        return bool(self._history)

    def record(self, msg: Message) -> None:
        if len(self._log) == self._log.maxlen:
            self._start += 1
        self._log.append(msg)

    def snapshot(self, belief: Belief, u, u_t, next_output: float, gates: dict) -> None:
        """Keep the belief (and the gates' states, ``{sensor: GateRun}``) after the messages logged so far."""
        self._history.append(Snapshot(belief.t, belief, u, next_output, self._start + len(self._log),
                                      {n: g.state for n, g in gates.items()},
                                      {n: g.counters.copy() for n, g in gates.items()}, u_t))

    def rewind(self, late: Message) -> tuple[Snapshot, list[Message]] | None:
        """The newest snapshot at or before ``late`` and the messages to re-run from it (``late`` among them, in
        time order), or None when ``late`` is older than the history. The log from the snapshot on and the
        snapshots after it give way to the re-run's own (the history stays valid for the next late message,
        which may be older than this one's re-run)."""
        snap = None
        for s in reversed(self._history):
            if s.t <= late.t and s.index >= self._start:
                snap = s
                break
        if snap is None:
            return None
        keep = snap.index - self._start
        rerun = list(itertools.islice(self._log, keep, None))
        rerun.append(late)
        rerun.sort(key=lambda m: m.t)
        while len(self._log) > keep:
            self._log.pop()
        while self._history and self._history[-1] is not snap:
            self._history.pop()
        return snap, rerun


def replay_late(late: Message, log: ReplayLog, processor, on_update: bool) -> Iterator:
    """A late message: the run rewound to the newest snapshot before it and the messages after it re-run through
    ``processor`` with it. Counted once, by what its re-run made of it (used, rejected, ...), with its events
    and NIS, and late only when it is older than the history; the re-run messages are not counted again."""
    sensors = processor.sensors
    sensor = sensors[late.sensor]
    rewound = log.rewind(late)
    if rewound is None:
        sensor.counters["late"] += 1
        yield Event(late.t, "late", late.sensor, "older than the replay history; dropped")
        return
    snap, rerun = rewound
    ig = processor.integrator
    processor.belief, ig.u, ig.next_output, ig.u_t = snap.belief, snap.u, snap.next_output, snap.u_t
    for n, state in snap.gates.items():
        # the gate decides the re-run messages again, and its counts are those of the re-run decisions
        processor.gates[n].state = state
        processor.gates[n].counters = snap.gate_counts[n].copy()
    counters = {n: dict(s.counters) for n, s in sensors.items()}
    own: dict[str, int] = {}      # the late message's own outcome in the re-run (used, rejected, ...)
    events: list = []             # and what it reported (a rejection, a geometry warning, its NIS)
    processor.quiet(True, False)
    try:
        for msg in rerun:
            log.record(msg)
            if msg is late:   # new to the run: its outcome, events and NIS are reported as in time order
                before = dict(sensor.counters)
                processor.quiet(True, True)
                try:
                    events += [e for e in processor.process(msg) if e.__class__ is not Estimate]
                finally:
                    processor.quiet(True, False)
                own = {k: v - before.get(k, 0) for k, v in sensor.counters.items() if v != before.get(k, 0)}
            else:
                for _ in processor.process(msg):
                    pass
            if sensors[msg.sensor].role != "input":   # as a run keeps them: after measurements
                processor.snapshot(rerun=True)
    finally:
        processor.quiet(False, False)
    for n, s in sensors.items():  # re-run messages were already counted
        s.counters.update(counters[n])
    for k, v in own.items():      # counted once, by its re-run outcome, not as late
        sensor.counters[k] += v
    processor.snapshot()
    yield from events
    yield Event(late.t, "replayed", late.sensor, f"re-ran {len(rerun)} messages")
    belief = processor.belief
    if on_update and belief is not None:
        yield Estimate(belief.t, belief, "update", late.sensor)
