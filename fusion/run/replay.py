"""``late_policy: replay``: a bounded log of the messages processed and snapshots of the belief (with the gates'
per-run states, values like the belief), and the rewind that says what to re-run for a late message. The
loop re-runs them (fusion.run.loop); this part only keeps and trims what a rewind needs."""
from __future__ import annotations

import itertools
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from fusion.api import Belief, Message

__all__ = ["Snapshot", "ReplayLog"]


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
