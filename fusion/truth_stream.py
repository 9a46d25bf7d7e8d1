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
  evaluated with what the window has, as at the end of the input. Evaluating takes what depends on the
  moment (the settle clock, the truth samples around the estimate and the fraction between them:
  ``ErrorTracker.locate``, ``TruthWindow.locate``); the arithmetic is done for ``SCORE_BATCH`` estimates at
  once (``ErrorTracker.score``, ``TruthWindow.rows``), to the same bits as one at a time, and ``flush``
  (called by ``finish``) brings the statistics up to date.

Memory: O(window + max_pending + SCORE_BATCH), whatever the length of the run.
"""
from __future__ import annotations

import bisect
import math
from collections import deque
from typing import Callable, Collection, Sequence

import numpy as np

from fusion import quaternion as quat
from fusion.api import Estimate, Message
from fusion.logformat import parse_values

__all__ = ["TruthWindow", "TruthComparison"]

_KEEP_BEHIND = 64  # samples kept before the oldest time still needed (estimates slightly out of order)


def _median(values: Collection[float]) -> float:
    """np.median of a few floats (the same number: the middle one, or the mean of the middle two) without
    np.median, whose first call imports numpy.ma (slow, at a run's start-up)."""
    v = sorted(values)
    n = len(v)
    return float(v[n // 2]) if n % 2 else float((v[n // 2 - 1] + v[n // 2]) / 2.0)


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
        if vals.__class__ is str:
            # unparsed values text (fusion.logformat.iter_messages raw_streams): the parser has checked
            # that it is len(names) finite numbers; parsed when interpolated (_Rows), or now to unwrap
            if vals.count(",") + 1 != len(self.names):  # type: ignore[attr-defined]
                self.skipped += 1
                return False
            row = vals if not self._angle_cols else self._unwrapped(parse_values(vals))
        else:
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
            row = vals if not self._angle_cols else self._unwrapped(vals)
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
        if n <= 64 or not n & 255:   # every 256th sample (the median of the intervals is not free)
            self.period = _median(self._intervals) if self._intervals else 0.0
        if len(ts) > self.max_samples:
            self._drop(len(ts) - self.max_samples)
        return True

    def _unwrapped(self, vals: Sequence[float]) -> tuple:
        arr = np.array(vals, dtype=float)
        self._unwrap_row(arr)
        return tuple(arr.tolist())

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
        where = self.locate(t)
        return None if where is None else self.rows([where])[0]

    def locate(self, t: float) -> tuple | None:
        """What :meth:`row` interpolates at ``t`` (s), taken now (the samples, the fraction), for
        :meth:`rows` to compute later even after the window has moved on: ``(sample, None, 0.0)`` for the
        first or last sample within half a period outside the span, ``(sample0, sample1, f)`` between two,
        None where truth is not defined. The same rules as fusion.truth.interpolate_row (the stored
        samples are immutable: text or tuples)."""
        tl = self._t
        n = len(tl)
        if n == 0:
            return None
        half = 0.5 * self.period
        if t < tl[0]:
            return (self._v[0], None, 0.0) if tl[0] - t <= half else None
        if t >= tl[-1]:
            return (self._v[n - 1], None, 0.0) if t - tl[-1] <= half else None
        i = bisect.bisect_right(tl, t)  # tl[i-1] <= t < tl[i]
        t0, t1 = tl[i - 1], tl[i]
        dt = t1 - t0
        if dt > self.GAP_PERIODS * self.period and min(t - t0, t1 - t) > half:
            return None
        return (self._v[i - 1], self._v[i], (t - t0) / dt if dt > 0 else 1.0)

    def rows(self, located: Sequence[tuple]) -> np.ndarray:
        """The rows (k, m) of :meth:`locate` results, all at once: the same numbers as ``row(t)`` gave when
        each was located (linear interpolation as one array expression, elementwise as fusion.truth.
        interpolate_row; quaternions by the same float slerp; angle columns wrapped)."""
        quats = list(self.quaternions.values())
        seen: dict[int, list[float]] = {}   # a sample shared by estimates (two sensors at one time): parsed once

        def floats(sample) -> list[float]:
            got = seen.get(id(sample))
            if got is None:
                got = seen[id(sample)] = _floats(sample, quats)
            return got

        first = [floats(w[0]) for w in located]
        out = np.array(first, dtype=float).reshape(len(located), len(self.names))
        inner = [k for k, w in enumerate(located) if w[1] is not None]
        if inner:
            second = [floats(located[k][1]) for k in inner]
            f = [located[k][2] for k in inner]
            v0 = out[inner]
            out[inner] = v0 + np.array(f)[:, None] * (np.array(second, dtype=float) - v0)
            for cols in quats:
                out[np.ix_(inner, cols)] = [
                    quat.slerp_lists([first[k][c] for c in cols], [second[j][c] for c in cols], f[j])
                    for j, k in enumerate(inner)]
        for c in self._angle_cols:
            out[:, c] = (out[:, c] + math.pi) % (2.0 * math.pi) - math.pi
        return out

    def at(self, t: float) -> dict[str, float] | None:
        row = self.row(t)
        return None if row is None else dict(zip(self.names, row.tolist()))


def _floats(sample, quats: list[list[int]]) -> list[float]:
    """A stored sample (text or tuple) as floats with its quaternion columns normalised, as :class:`_Rows`."""
    vals = list(parse_values(sample))
    for cols in quats:
        w, x, y, z = vals[cols[0]], vals[cols[1]], vals[cols[2]], vals[cols[3]]
        nrm = math.sqrt(w * w + x * x + y * y + z * z)
        if nrm > 0.0:
            for c in cols:
                vals[c] = vals[c] / nrm
    return vals


class _Rows:
    """The stored samples as interpolate_row reads them: row i as a float array with its quaternion
    columns normalised (as fusion.metrics.Truth normalises them when it is built)."""

    __slots__ = ("_v", "_quats")

    def __init__(self, values: list, quaternions: dict[str, list[int]]):
        self._v, self._quats = values, quaternions

    def __getitem__(self, i: int) -> np.ndarray:
        vals = list(parse_values(self._v[i]))
        for cols in self._quats.values():
            # as Truth normalises all rows at once (np.linalg.norm over a row of 4 sums its squares in order,
            # left to right: the same last bit, tests/core/test_raw_truth_values.py), in plain floats
            w, x, y, z = vals[cols[0]], vals[cols[1]], vals[cols[2]], vals[cols[3]]
            nrm = math.sqrt(w * w + x * x + y * y + z * z)
            if nrm > 0.0:
                for c in cols:
                    vals[c] = vals[c] / nrm
        return np.array(vals, dtype=float)


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
        # Estimates evaluated (where truth is at their time taken: ErrorTracker.locate) whose arithmetic waits
        # to be done for SCORE_BATCH at once (ErrorTracker.score): the same numbers, a fraction of the numpy
        # calls. With on_result, the unlocated ones wait in line too (None), so it sees every estimate in order.
        self._located: list[tuple[Estimate, tuple | None]] = []

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
        self.flush()

    def flush(self) -> None:
        """Score the estimates evaluated so far (the tracker's statistics are then up to date)."""
        located, self._located = self._located, []
        items = [it for _, it in located if it is not None]
        outs: list = []
        rows = None
        if items:
            outs, rows = self.tracker.score(items, want=self.on_result is not None)
        if self.on_result is not None:
            k = 0
            for estimate, item in located:
                if item is None:
                    self.on_result(estimate, None, None)
                else:
                    self.on_result(estimate, outs[k], rows[k].copy())  # type: ignore[index]
                    k += 1

    def _release(self, newest: float) -> None:
        pend = self._pending
        # An estimate at t is final once a sample after t has arrived (strictly: a sample at exactly t
        # interpolates with the one after it, as the whole-recording Truth does).
        while pend and pend[0].t < newest:
            self._evaluate(pend.popleft())
        if len(self.window._t) > 4 * _KEEP_BEHIND:  # trim now and then, not at every sample (len(): no call)
            self.window.forget_before(pend[0].t if pend else self._last_t)

    #: Estimates scored at once (bounded memory: at most this many beliefs wait besides ``max_pending``).
    SCORE_BATCH = 64

    def _evaluate(self, estimate: Estimate) -> None:
        item = self.tracker.locate(estimate)
        self._last_t = estimate.t
        if item is not None or self.on_result is not None:
            self._located.append((estimate, item))
            if len(self._located) >= self.SCORE_BATCH:
                self.flush()
