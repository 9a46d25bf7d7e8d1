"""State histories for the state plot: each non-quaternion state element's estimate and 1-sigma, and its
error against truth when the stream carries truth lines, decimated to one sample per ``dt`` s of sensor
time, bounded (worker thread).

The error is ``x_hat - x_true`` with the truth linearly interpolated to the estimate's time between the
two truth lines around it: a sample waits (``pending``) until a truth line at or after its time has
arrived, at most ``wait_s`` seconds of sensor time; nan when no truth brackets the estimate, the stream
has no truth, or truth lacks the element.
Quaternion blocks are left out (their error is an angle, not an element difference).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Callable

import numpy as np

from fusion.api import Estimate, Message, StateLayout


@dataclass(frozen=True)
class StateSample:
    """At sensor time ``t``: estimate, 1-sigma and error (nan: no truth) of each element in ``names``."""

    t: float
    x: tuple[float, ...]
    sd: tuple[float, ...]
    err: tuple[float, ...]


class StateHistory:
    """``names``/``index``: the plotted elements and their indices in the state vector; ``truth_names``
    returns the truth line's field names (None until the header gives them); ``truth_keep``: truth lines
    kept for interpolation (more for estimates that arrive late, the fixed-lag smoothed ones)."""

    def __init__(self, layout: StateLayout, truth_names: Callable[[], list[str] | None], maxlen: int = 600,
                 dt: float = 0.1, wait_s: float = 1.0, truth_keep: int = 64):
        self.names: list[str] = []
        idx: list[int] = []
        for block in layout.blocks:
            if block.kind == "quaternion":
                continue
            start = layout[block.name].start
            for k, name in enumerate(block.element_names()):
                self.names.append(name)
                idx.append(start + k)
        self.index = np.array(idx, dtype=np.int64)
        self._truth_names = truth_names
        self._cols: np.ndarray | None = None  # truth column of each element (-1: absent)
        self._truth: deque[tuple[float, np.ndarray]] = deque(maxlen=truth_keep)  # the newest truth lines
        self.samples: deque[StateSample] = deque(maxlen=maxlen)
        self.dt = dt
        self._last_t = -math.inf
        self.wait_s = wait_s
        self.pending: deque[tuple[float, np.ndarray, np.ndarray]] = deque()

    def on_truth(self, msg: Message) -> None:
        if self._cols is None:
            names = self._truth_names()
            if not names:
                return
            self._cols = np.array([names.index(n) if n in names else -1 for n in self.names], dtype=np.int64)
        try:
            values = np.array([float(v) for v in msg.values], dtype=float)
        except (TypeError, ValueError):
            return
        row = np.array([values[c] if 0 <= c < values.size else math.nan for c in self._cols], dtype=float)
        self._truth.append((msg.t, row))
        self._resolve(msg.t)

    def _resolve(self, newest: float, now: float = -math.inf) -> None:
        """Move the pending samples that truth now brackets (newest truth time ``newest``), or that waited
        longer than ``wait_s`` by sensor time ``now``, to ``samples``."""
        pend = self.pending
        while pend and (pend[0][0] <= newest or now - pend[0][0] > self.wait_s):
            t, x, sd = pend.popleft()
            true = self._true_at(t)
            err = x - true if true is not None else np.full(x.size, np.nan)
            self.samples.append(StateSample(t, tuple(x.tolist()), tuple(sd.tolist()), tuple(err.tolist())))

    def _true_at(self, t: float) -> np.ndarray | None:
        before = after = None
        for tt, row in reversed(self._truth):
            if tt <= t:
                before = (tt, row)
                break
            after = (tt, row)
        if before is None or after is None:
            if before is not None and before[0] == t:
                return before[1]
            return None
        (t0, r0), (t1, r1) = before, after
        w = (t - t0) / (t1 - t0) if t1 > t0 else 0.0
        return r0 + w * (r1 - r0)

    def on_estimate(self, est: Estimate) -> None:
        if est.t - self._last_t < self.dt:
            return
        self._last_t = est.t
        x = np.asarray(est.belief.x, dtype=float)[self.index]
        sd = np.asarray(est.belief.sd, dtype=float)[self.index]
        if self._cols is None and not self._truth_names():  # no truth in this stream
            self.samples.append(StateSample(est.t, tuple(x.tolist()), tuple(sd.tolist()), (math.nan,) * x.size))
            return
        self.pending.append((est.t, x, sd))
        self._resolve(self._truth[-1][0] if self._truth else -math.inf, est.t)

    def snapshot(self) -> tuple[StateSample, ...]:
        return tuple(self.samples)
