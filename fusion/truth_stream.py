"""Truth (or a reference estimator's output) as a stream: errors of a run in bounded memory.

A recording interleaves ``truth`` lines with the sensor lines. ``fusion.metrics.Truth`` needs every
sample up front; a run of hours (or a live port) cannot keep them. Here:

- ``TruthWindow`` keeps the recent truth samples only (a window that follows the estimates) and
  interpolates exactly as ``Truth.row`` does: linearly, quaternions by slerp, angle columns unwrapped,
  ``None`` outside the span by more than half the median sample period and inside a gap of more than
  ``GAP_PERIODS`` periods farther than half a period from both ends.
- ``TruthComparison`` holds the estimates that truth has not yet passed (an estimate at ``t`` needs the
  first sample after ``t``) and feeds each to a ``fusion.metrics.ErrorTracker`` as soon as it can be
  interpolated, in order, so the statistics equal those of the whole-recording ``Truth`` (the sample
  period is the median over the window rather than over the whole recording: the same for a regular
  truth rate). At most ``max_pending`` estimates wait: past that (truth has stopped) the oldest is
  evaluated with what the window has, as at the end of the input.

Memory: O(window + max_pending), whatever the length of the run.
"""
from __future__ import annotations

import bisect
import math
from collections import deque
from typing import Callable, Collection, Sequence

import numpy as np

from fusion.api import Estimate, Message
from fusion.metrics import interpolate_row

__all__ = ["TruthWindow", "TruthComparison"]

_KEEP_BEHIND = 64  # samples kept before the oldest time still needed (estimates slightly out of order)


def _median(values) -> float:
    """np.median of a few floats (the same number: the middle one, or the mean of the two middle ones as
    (a + b) / 2), in plain Python: np.median's first call imports numpy.ma (~7 ms of a run's start)."""
    s = sorted(values)
    m = len(s) // 2
    return float(s[m]) if len(s) % 2 else (s[m - 1] + s[m]) / 2.0


class TruthWindow:
    """The recent samples of a truth stream, with ``Truth``'s interface for ``ErrorTracker``.

    :param names: the block-prefixed column names (``# fields truth px py ...``).
    :param max_samples: the window never holds more (the oldest go first).
    """

    GAP_PERIODS = 5.0
    PERIOD_WINDOW = 1024  # the sample period is the median of the last this-many intervals

    def __init__(self, names: Sequence[str], max_samples: int = 16384):
        self.names: tuple[str, ...] = tuple(names)
        if not self.names:
            raise ValueError("truth needs its field names ('# fields truth px py ...' in the log header)")
        self.index: dict[str, int] = {n: i for i, n in enumerate(self.names)}
        self.angles: frozenset[str] = frozenset()
        self._angle_cols: list[int] = []
        self.quaternions: dict[str, list[int]] = {}
        for n in self.names:
            if n.endswith("w") and all(n[:-1] + a in self.index for a in "xyz"):
                self.quaternions[n[:-1]] = [self.index[n[:-1] + a] for a in "wxyz"]
        self.max_samples = int(max_samples)
        self._t: list[float] = []
        self._v: list[np.ndarray] = []
        self._intervals: deque[float] = deque(maxlen=self.PERIOD_WINDOW)
        self.period = 0.0
        self.newest = -math.inf
        self.received = 0  # samples accepted over the whole run
        self.skipped = 0   # truth lines that were not len(names) finite numbers
        self._raw_prev: np.ndarray | None = None  # last raw angle values (unwrapping, as np.unwrap)
        self._unwrap = np.zeros(0)

    def with_angles(self, names: Collection[str]) -> "TruthWindow":
        """Declare the columns ``names`` (rad) as angles (before the first sample): unwrapped along the
        stream, interpolated the shorter way, wrapped on output. Returns self."""
        if self.received:
            raise RuntimeError("angle columns must be declared before the first truth sample")
        self.angles = frozenset(set(self.angles) | {a for a in names if a in self.index})
        self._angle_cols = [self.index[a] for a in sorted(self.angles)]
        self._unwrap = np.zeros(len(self._angle_cols))
        return self

    def __len__(self) -> int:
        return len(self._t)

    def __repr__(self) -> str:
        span = f"{self._t[0]:.3f}..{self._t[-1]:.3f} s" if self._t else "empty"
        return f"TruthWindow({len(self)} of {self.received} samples, {span}, fields {' '.join(self.names)})"

    # ------------------------------------------------------------------ input
    def add(self, message: Message) -> bool:
        """Take one truth message; False (and counted in ``skipped``) unless it has ``len(names)`` finite
        numbers."""
        vals = message.values
        if len(vals) != len(self.names):
            self.skipped += 1
            return False
        # Kept as the parsed tuple (a truth line arrives at every IMU sample, an estimate is compared far
        # less often): converted to an array, quaternions normalised, only when interpolated (_Rows).
        # The log parser already refuses NaN and inf; a label among the values is not a number.
        try:
            total = sum(vals)
        except TypeError:  # a label among the values
            self.skipped += 1
            return False
        if total - total != 0.0:  # a NaN or inf (from a caller other than the parser)
            if not all(math.isfinite(float(v)) for v in vals):
                self.skipped += 1
                return False
        row = vals
        if self._angle_cols:
            arr = np.array(vals, dtype=float)
            self._unwrap_row(arr)
            row = tuple(arr.tolist())
        t = float(message.t)
        ts = self._t
        if ts and t < ts[-1]:  # out of order: insert in place
            i = bisect.bisect_right(ts, t)
            ts.insert(i, t)
            self._v.insert(i, row)
        else:
            if ts:
                self._intervals.append(t - ts[-1])
            ts.append(t)
            self._v.append(row)
        if t > self.newest:
            self.newest = t
        n = self.received = self.received + 1
        if n <= 64 or not n & 255:   # every 256th sample (the median of the intervals costs ~20 us)
            self.period = _median(self._intervals) if self._intervals else 0.0
        if len(ts) > self.max_samples:
            self._drop(len(ts) - self.max_samples)
        return True

    def _unwrap_row(self, row: np.ndarray) -> None:
        """Unwrap the angle columns against the previous sample, as ``np.unwrap`` does along a column."""
        cols = self._angle_cols
        raw = row[cols].copy()
        if self._raw_prev is not None:
            dd = raw - self._raw_prev
            ddmod = np.mod(dd + math.pi, 2.0 * math.pi) - math.pi
            ddmod[(ddmod == -math.pi) & (dd > 0)] = math.pi
            corr = ddmod - dd
            corr[np.abs(dd) < math.pi] = 0.0
            self._unwrap = self._unwrap + corr
        self._raw_prev = raw
        row[cols] = raw + self._unwrap

    def forget_before(self, t: float) -> None:
        """Drop samples no longer needed to interpolate at times >= ``t`` (a margin is kept)."""
        i = bisect.bisect_right(self._t, t) - 1 - _KEEP_BEHIND
        if i > 0:
            self._drop(i)

    def _drop(self, k: int) -> None:
        del self._t[:k]
        del self._v[:k]

    # ------------------------------------------------------------------ output (as fusion.metrics.Truth)
    def row(self, t: float) -> np.ndarray | None:
        """The interpolated truth row at ``t`` (s), or None where truth is not defined (see the module)."""
        return interpolate_row(self._t, _Rows(self._v, self.quaternions), t, self.period, self.GAP_PERIODS,
                               self.quaternions, self._angle_cols)

    def at(self, t: float) -> dict[str, float] | None:
        row = self.row(t)
        return None if row is None else dict(zip(self.names, row.tolist()))


class _Rows:
    """The stored samples as interpolate_row reads them: row i as a float array with its quaternion
    columns normalised (as fusion.metrics.Truth normalises them when it is built)."""

    __slots__ = ("_v", "_quats")

    def __init__(self, values: list, quaternions: dict[str, list[int]]):
        self._v, self._quats = values, quaternions

    def __getitem__(self, i: int) -> np.ndarray:
        row = np.array(self._v[i], dtype=float)
        if self._quats:
            vals = row.tolist()
            for cols in self._quats.values():
                # as Truth does it over all rows at once (np.linalg.norm's sum of squares, left to right: the
                # same last bit), in plain floats: ~2 us against ~8 us for the numpy calls on one row
                a, b, c, d = [vals[j] for j in cols]
                nrm = math.sqrt(a * a + b * b + c * c + d * d)
                if nrm > 0.0:
                    row[cols] = (a / nrm, b / nrm, c / nrm, d / nrm)
        return row


class TruthComparison:
    """Errors of a stream of estimates against a truth stream, in bounded memory (see the module).

    :param tracker: a ``fusion.metrics.ErrorTracker`` (created without truth); its truth is set to this
        comparison's window.
    :param names: the truth column names.
    :param on_result: called with ``(estimate, errors_or_None, truth_row_or_None)`` for every estimate, in
        order, once it has been evaluated (a plot keeps what it needs from it).
    """

    def __init__(self, tracker, names: Sequence[str], on_result: Callable | None = None,
                 max_pending: int = 4096, max_samples: int = 16384):
        self.window = TruthWindow(names, max_samples=max_samples)
        self.tracker = tracker
        tracker.set_truth(self.window)
        self.on_result = on_result
        self.max_pending = int(max_pending)
        self._pending: deque[Estimate] = deque()
        self._last_t = -math.inf  # time of the last estimate evaluated

    def add_truth(self, message: Message) -> None:
        w = self.window
        if w.add(message):
            pend = self._pending
            if (pend and pend[0].t < w.newest) or len(w._t) > 4 * _KEEP_BEHIND:   # else _release does nothing
                self._release(w.newest)

    def add_estimate(self, estimate: Estimate) -> None:
        self._pending.append(estimate)
        if len(self._pending) > self.max_pending:
            self._evaluate(self._pending.popleft())
        self._release(self.window.newest)

    def finish(self) -> None:
        """End of input: evaluate what is still waiting with the truth there is."""
        while self._pending:
            self._evaluate(self._pending.popleft())

    def _release(self, newest: float) -> None:
        pend = self._pending
        # An estimate at t is final once a sample after t has arrived (strictly: a sample at exactly t
        # interpolates with the one after it, as the whole-recording Truth does).
        while pend and pend[0].t < newest:
            self._evaluate(pend.popleft())
        if len(self.window._t) > 4 * _KEEP_BEHIND:  # trim now and then, not at every sample (len(): no call)
            self.window.forget_before(pend[0].t if pend else self._last_t)

    def _evaluate(self, estimate: Estimate) -> None:
        errors = self.tracker.add(estimate)
        self._last_t = estimate.t
        if self.on_result is not None:
            self.on_result(estimate, errors, self.window.row(float(estimate.t)) if errors is not None else None)
