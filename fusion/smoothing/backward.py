r"""The backward pass: the Rauch-Tung-Striebel recursion over the recorded chain (full or fixed-lag).

Full smoother (:func:`smooth`): from the last node (x^s_K = x_K, P^s_K = P_K) back to the first, one
backward step a recorded transition (``fusion_plugins.filters.rts.rts_step`` / ``rts_step_sqrt``), the
mean normalised by the process model (quaternion blocks to unit norm) and angle blocks differenced
with wrapping. The smoothed belief of a node is given to every estimate noted at that node; they are
written to a :class:`ChunkStore` last to first and read back first to last (:func:`smoothed_estimates`).

Fixed-lag smoother (:class:`FixedLag`): keeps the transitions of the last ``lag`` seconds (and the
estimates waiting in them) and emits an estimate once the filter gives one ``lag`` s past it, smoothed
by the backward recursion from that newer estimate's filtered belief, i.e. on all the measurements up to
then.
Memory is bounded by the window; at the end of the run what waits is smoothed on everything, so a lag
longer than the run gives the full smoother.
"""
from __future__ import annotations

import math
from collections import deque
from typing import Any, Callable, Iterator

import numpy as np

from fusion.api import Belief, Estimate

from .record import ForwardLog
from .store import ChunkStore

__all__ = ["smooth", "smoothed_estimates", "FixedLag", "state_difference"]


def state_difference(layout) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``a - b`` for states of ``layout``, wrapped to (-pi, pi] in the elements of angle blocks."""
    idx = [i for blk in layout.blocks if blk.kind == "angle" for i in range(layout[blk.name].start,
                                                                              layout[blk.name].stop)]
    if not idx:
        return np.subtract
    ang = np.array(idx, dtype=int)

    def diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        d = a - b
        d[ang] = (d[ang] + math.pi) % (2.0 * math.pi) - math.pi
        return d
    return diff


_STEPS: tuple | None = None


def _steps() -> tuple:
    """(rts_step, rts_step_sqrt) of fusion_plugins.filters.rts, imported once (the core does not import
    plugins at start-up)."""
    global _STEPS
    if _STEPS is None:
        from fusion_plugins.filters.rts import rts_step, rts_step_sqrt
        _STEPS = (rts_step, rts_step_sqrt)
    return _STEPS


def _back(rec: dict, xs: np.ndarray, Cs: np.ndarray, sqrt: bool, normalize, diff) -> tuple[np.ndarray, np.ndarray]:
    """One backward step over the transition ``rec`` from the smoothed belief (xs, Cs) after it. A
    non-finite one (the filter diverged later) stops at a break of the chain (G = 0; the forward log
    breaks where a belief turns non-finite): the smoothed belief before it is the filtered one, where
    the formula would give 0 * NaN = NaN."""
    rts_step, rts_step_sqrt = _STEPS or _steps()
    if not math.isfinite(float(xs.sum()) + float(Cs.sum())) and not rec["G"].any():
        return np.array(rec["x"], dtype=float), np.array(rec["A"], dtype=float)
    if sqrt:
        xs, Cs = rts_step_sqrt(rec["x"], rec["A"], rec["G"], rec["x1"], xs, Cs, diff)
    else:
        xs, Cs = rts_step(rec["x"], rec["A"], rec["G"], rec["x1"], rec["P1"], xs, Cs, diff)
    return normalize(xs), Cs


def smooth(log: ForwardLog, normalize, diff, out: ChunkStore) -> int:
    """Run the backward pass over ``log``; append the smoothed estimates (last to first) to ``out``.
    Returns the number of nodes smoothed."""
    final = log.final()
    if final is None:
        return 0
    xs, Cs = final
    node = log.nodes
    ests = log.estimates.rows_reversed()
    est = next(ests, None)

    def emit(node: int, xs: np.ndarray, Cs: np.ndarray):
        nonlocal est
        while est is not None and int(est["node"]) == node:
            out.append(t=est["t"], x=xs, C=Cs, reason=est["reason"], sensor=est["sensor"])
            est = next(ests, None)

    emit(node, xs, Cs)
    sqrt = log.sqrt
    for rec in log.steps.rows_reversed():
        node -= 1
        xs, Cs = _back(rec, xs, Cs, sqrt, normalize, diff)
        emit(node, xs, Cs)
    return log.nodes + 1


def _estimate(row: dict, sqrt: bool, sensors: list[str]) -> Estimate:
    t = float(row["t"])
    x = np.array(row["x"], dtype=float)
    C = np.array(row["C"], dtype=float)
    b = Belief(t, x, S=C) if sqrt else Belief(t, x, P=C)
    sensor = sensors[int(row["sensor"])] or None
    return Estimate(t, b, ForwardLog.REASONS[int(row["reason"])], sensor)


def smoothed_estimates(out: ChunkStore, sqrt: bool, sensors: list[str], forward: bool = False
                       ) -> Iterator[Estimate]:
    """The smoothed estimates of a store, first to last: :func:`smooth`'s (written last to first), or
    with ``forward`` one written in order (the fixed-lag smoother's)."""
    for row in (out.forward_rows() if forward else out.rows_reversed()):
        yield _estimate(row, sqrt, sensors)


class FixedLag:
    """Fixed-lag smoothing as the forward pass goes (see the module): ``on_step`` is the log's
    transition callback, ``on_estimate`` the forward run's sink; ``emit`` gets each smoothed estimate,
    ``lag`` s of sensor time after the filter gave it (all of them by ``finish``)."""

    def __init__(self, log_sqrt: bool, lag: float, normalize, diff, emit: Callable[[Estimate], Any]):
        self.sqrt = log_sqrt
        self.lag = float(lag)
        self.normalize = normalize
        self.diff = diff
        self.emit = emit
        self.log: ForwardLog | None = None
        self.window: deque[tuple[int, dict]] = deque()      # (node, record), oldest first
        self.pending: deque[tuple[int, Estimate]] = deque()  # (node, filtered estimate), oldest first
        self.emitted = 0
        self.largest_window = 0

    def on_step(self, node: int, rec: dict) -> None:
        rec = {k: v for k, v in rec.items()}
        self.window.append((node, rec))
        self.largest_window = max(self.largest_window, len(self.window))

    def on_estimate(self, est: Estimate, node: int | None = None) -> None:
        """A filtered estimate at ``node`` (default: the open node); releases those ``lag`` s older,
        smoothed back from this estimate's belief (so what an estimate gets does not depend on how late
        the caller hands the estimates over)."""
        log = self.log
        assert log is not None
        node = log.nodes if node is None else node
        self.pending.append((node, est))
        b = est.belief
        self._release(est.t - self.lag, (node, b.x, log.backend.final(b)))

    def _release(self, until: float, start: tuple[int, np.ndarray, np.ndarray] | None = None) -> None:
        """Emit the estimates at or before ``until`` (s), smoothed back from ``start`` = (node, mean,
        covariance or factor), by default the open node's filtered belief (everything recorded so far)."""
        pend = self.pending
        if not pend or pend[0][1].t > until:
            return
        due = 0
        while due < len(pend) and pend[due][1].t <= until:
            due += 1
        first_node = pend[0][0]
        log = self.log
        assert log is not None and log.current is not None
        if start is None:
            xs, Cs = log.final()  # type: ignore[misc]
            node = log.nodes
        else:
            node, xs, Cs = start
        out: list[Estimate] = []
        k = due - 1
        recs = [r for n, r in self.window if first_node <= n < node]
        j = len(recs)
        while k >= 0:
            pnode, est = pend[k]
            while node > pnode:
                j -= 1
                node -= 1
                xs, Cs = _back(recs[j], xs, Cs, self.sqrt, self.normalize, self.diff)
            b = Belief(est.t, xs, S=Cs) if self.sqrt else Belief(est.t, xs, P=Cs)
            out.append(Estimate(est.t, b, est.reason, est.sensor))
            k -= 1
        for _ in range(due):
            pend.popleft()
        for e in reversed(out):
            self.emit(e)
            self.emitted += 1
        keep_from = pend[0][0] if pend else log.nodes
        while self.window and self.window[0][0] < keep_from:
            self.window.popleft()

    def finish(self) -> None:
        self._release(math.inf)

    def close(self) -> None:
        self.finish()
