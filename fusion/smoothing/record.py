"""The forward pass of a smoother: what the filter does, recorded as a chain of nodes and transitions.

:class:`RecordingFilter` stands in for the system's filter (the scheduler drives it like any filter:
``initial_belief``, ``predict``, ``predict_inputs``, ``update``; everything else is the wrapped
filter's). It calls the wrapped filter, so the forward estimates are the filter's own numbers, and its
smoother backend (``fusion_plugins.filters.rts``) adds the transition terms of each prediction.

The chain (``ForwardLog``): a *node* is the belief between two predictions; updates change the node's
filtered belief in place (same time); a prediction closes the node with one record (filtered mean and
covariance or conditional factor, gain, predicted mean and covariance) and opens the next. A belief that
does not come from the last one (a reset by recovery, a re-initialisation) closes the node with a zero
gain: the smoothed belief before a break is the filtered one. So does a prediction that holds one input
sample for longer than the input sensor's ``max_gap`` (``max_hold``: every stream paused, or the IMU
silent while the others go on): across such a gap the prediction is not the process model's transition
but a coast with the vehicle's assumed motion as noise (the INS's ``hold_after`` model), and its
cross-covariance is not one the backward pass can use. Over an 8 s pause of a car's recording the
linearised EKF transition kept one direction of the attitude noise-free (the hold noise is expressed at
the attitude before the hold, which then turns under the held rate), and the backward pass regressed the
attitude correction after the pause onto the estimates before it: 8 deg of error, 0.4 deg filtered (the
srukf carried the norm of a 90 deg quaternion difference back instead). And so does a prediction or update
that takes a finite belief to a non-finite one (the filter diverged): the backward pass stops a non-finite
smoothed belief at a break, so the estimates before the divergence are smoothed as in the run cut there. Each estimate the scheduler emits is noted
with the node it belongs to, so the backward pass can give the smoothed belief at every output: the
node whose filtered belief it carries (looked up among the last ``RECENT`` nodes), not merely the open
one, because a caller may see an estimate after the filter has moved on (``fusion.pipeline.Run.push``
hands its sinks every estimate of a message only once the scheduler has released them all).
"""
from __future__ import annotations

import copy
import math
from collections import deque
from typing import Any, Callable

import numpy as np

from fusion.api import Belief, Estimate, Message

from .store import ChunkStore

__all__ = ["ForwardLog", "RecordingFilter"]


def _finite(b: Belief) -> bool:
    """The belief's mean and covariance (or factor) are finite (tested by a sum: NaN or inf anywhere makes
    it non-finite, and finite values summing past 1e308 do not occur in a filter that has not diverged)."""
    C = b.S if b.S is not None else b.P
    return math.isfinite(float(b.x.sum()) + (float(C.sum()) if C is not None else 0.0))


def _same(a: Belief, b: Belief | None) -> bool:
    """b is a (possibly re-timed, ``with_``) copy of a: the same mean and covariance objects."""
    return b is not None and (a is b or (a.x is b.x and a.P is b.P and a.S is b.S))


class ForwardLog:
    """The records of a forward pass: ``steps`` (one a transition), ``estimates`` (time, node, reason,
    sensor of each emitted estimate), ``truth`` (truth lines, for the smoothed errors) and the open node.

    :param on_step: called with ``(node_index, record)`` after each transition record (the fixed-lag
        smoother keeps a window of them); None for the full smoother.
    :param max_hold: s: a prediction that holds one input sample longer than this breaks the chain (the
        input sensor's ``max_gap``, see the module); None: never.
    """

    REASONS = ("update", "output")
    RECENT = 256   # nodes whose beliefs are kept to place a late-noted estimate

    def __init__(self, backend, n: int, chunk: int = 1024, disk: bool | None = None,
                 on_step: Callable[[int, dict], Any] | None = None, keep: bool = True,
                 max_hold: float | None = None):
        self.backend = backend
        self.sqrt = backend.sqrt
        self.n = n
        self.keep = keep
        self.steps = ChunkStore(chunk, disk)
        self.estimates = ChunkStore(chunk * 4, disk)
        self.truth = ChunkStore(chunk * 4, disk)
        self._truth_width = 0
        self.sensors: list[str] = []
        self.current: Belief | None = None
        self.nodes = 0          # index of the open node = records so far
        self.breaks = 0
        self.gap_breaks = 0     # of them, at an input sample held longer than max_hold
        self.nonfinite_breaks = 0   # of them, where the belief became non-finite (the filter diverged)
        self.max_hold = max_hold
        self._held_u: bytes | None = None        # the input sample the last prediction ended holding
        self._held_s = 0.0                       # s it has been held (applied) so far
        self.unmatched = 0      # estimates whose belief is no recent node's (mapped to the open node)
        self._recent: deque[tuple[int, Belief]] = deque(maxlen=self.RECENT)  # (node, a belief it had)
        self.on_step = on_step

    def __deepcopy__(self, memo) -> "ForwardLog":
        return self

    # ------------------------------------------------------------------ the chain
    def _record(self, step, b1: Belief | None = None) -> None:
        """Close the open node with ``step`` (its ``b1`` opens the next node, unless ``b1`` is given)."""
        b0 = self.current
        assert b0 is not None
        b1 = step.b1 if b1 is None else b1
        rec = {"x": b0.x, "A": step.A, "G": step.G, "x1": b1.x}
        if not self.sqrt:
            rec["P1"] = b1.P if b1.P is not None else b1.cov
        if self.keep:
            self.steps.append(**rec)
        if self.on_step is not None:
            self.on_step(self.nodes, rec)
        self.nodes += 1
        self.set_current(b1)

    def set_current(self, b: Belief) -> None:
        """The open node's filtered belief is now ``b`` (after a prediction, an update or a break)."""
        self.current = b
        self._recent.append((self.nodes, b))

    def enter(self, b: Belief) -> None:
        """The belief the filter is given next: a break of the chain unless it is the open node's."""
        if self.current is None:
            self.set_current(b)
        elif not _same(self.current, b):
            self.breaks += 1
            self._record(self.backend.broken(self.current))
            self.set_current(b)

    def transition(self, step) -> None:
        if step is not None:
            self._record(step)

    def held_too_long(self, us: np.ndarray | None, dts) -> bool:
        """Note a prediction that applies the input samples ``us`` (k, m), sample j over ``dts[j]`` (s);
        True when it holds one of them longer than ``max_hold`` s in all. Each sample of a run is a new
        sample, except the first when it is the one the last prediction ended with (the scheduler
        gives the held sample first): its time so far is added (a hold cut into several predictions
        by the measurements that arrive during an input gap)."""
        if us is None or self.max_hold is None:
            return False
        dl = dts.tolist() if isinstance(dts, np.ndarray) else [float(d) for d in dts]  # ~10 plain floats
        if not dl:
            return False
        us = np.asarray(us, dtype=float)
        if us[0].tobytes() == self._held_u:          # the bytes of a float array: cheaper than an element-wise compare
            dl[0] += self._held_s
        self._held_u, self._held_s = us[-1].tobytes(), dl[-1]
        return max(dl) > self.max_hold

    def cut(self, step, gap: bool = True) -> None:
        """Record the transition ``step`` as a break of the chain (zero gain, see the module): the
        smoothed belief before it is the filtered one; the predicted belief opens the next node.
        ``gap``: a hold longer than ``max_hold``, else a non-finite prediction."""
        if step is None:
            return
        self.breaks += 1
        if gap:
            self.gap_breaks += 1
        else:
            self.nonfinite_breaks += 1
        self._record(self.backend.broken(self.current), b1=step.b1)

    def predicted(self, b1: Belief, step, us: np.ndarray | None, dts) -> None:
        """Record a prediction to ``b1`` with the terms ``step`` (None: the belief did not move): a
        transition, or a break when it holds an input sample too long (:meth:`held_too_long`) or when
        it takes a finite belief to a non-finite one (the filter diverged: NaN times a zero gain is
        still NaN, so without the break the backward pass would carry the NaN over the whole run)."""
        if self.held_too_long(us, dts):
            self.cut(step)
        elif step is not None and not _finite(b1) and _finite(self.current):
            self.cut(step, gap=False)
        else:
            self.transition(step)

    def updated(self, b: Belief) -> None:
        """The open node's filtered belief is now the updated ``b``; an update that makes a finite belief
        non-finite breaks the chain there (see :meth:`predicted`)."""
        if not _finite(b) and _finite(self.current):
            self.breaks += 1
            self.nonfinite_breaks += 1
            self._record(self.backend.broken(self.current), b1=b)
        else:
            self.set_current(b)

    def node_of(self, est: Estimate) -> int:
        """The node whose filtered belief ``est`` carries: the open one, else the newest recent node that
        had it (``unmatched`` counts the estimates matching none; they are placed at the open node)."""
        b = est.belief
        if _same(b, self.current):
            return self.nodes
        for node, seen in reversed(self._recent):
            if _same(b, seen):
                return node
        self.unmatched += 1
        return self.nodes

    def note_estimate(self, est: Estimate) -> int | None:
        """Note an emitted estimate at its node (see the module); returns the node (None before the first
        belief)."""
        if self.current is None:
            return None
        node = self.node_of(est)
        reason = self.REASONS.index(est.reason) if est.reason in self.REASONS else 0
        if self.keep:
            self.estimates.append(t=float(est.t), node=node, reason=reason, sensor=self.sensor_code(est.sensor))
        return node

    def sensor_code(self, sensor: str | None) -> int:
        """A small integer for a sensor name (the stores hold numbers)."""
        sensor = sensor or ""
        try:
            return self.sensors.index(sensor)
        except ValueError:
            self.sensors.append(sensor)
            return len(self.sensors) - 1

    def note_truth(self, msg: Message) -> None:
        try:
            values = [float(v) for v in msg.values]
        except (TypeError, ValueError):
            return
        if self.truth.rows and len(values) != self._truth_width:
            return
        self._truth_width = len(values)
        self.truth.append(t=float(msg.t), v=np.asarray(values))

    def final(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(mean, covariance or factor) of the last node."""
        if self.current is None:
            return None
        return self.current.x, self.backend.final(self.current)

    def close(self) -> None:
        for s in (self.steps, self.estimates, self.truth):
            s.close()

    @property
    def bytes_on_disk(self) -> int:
        return self.steps.bytes_on_disk + self.estimates.bytes_on_disk + self.truth.bytes_on_disk


class RecordingFilter:
    """The system's filter with its forward pass recorded in ``log`` (see the module). Deep copies (the
    scheduler's) copy the wrapped filter and share the log."""

    def __init__(self, inner, log: ForwardLog):
        self.__dict__["inner"] = inner
        self.__dict__["log"] = log

    def __getattr__(self, name: str):
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.__dict__["inner"], name)

    def __deepcopy__(self, memo) -> "RecordingFilter":
        inner = copy.deepcopy(self.inner, memo)
        log = self.log
        log.backend = type(log.backend)(inner)
        return RecordingFilter(inner, log)

    def initial_belief(self, t: float, x: np.ndarray, P: np.ndarray) -> Belief:
        b = self.inner.initial_belief(t, x, P)
        self.log.enter(b)
        return b

    def predict(self, belief: Belief, process, u, dt: float) -> Belief:
        log = self.log
        log.enter(belief)
        b1, step = log.backend.predict(belief, process, u, dt)
        log.predicted(b1, step, None if u is None else np.asarray(u)[None], (dt,))
        return b1

    def predict_inputs(self, belief: Belief, process, us: np.ndarray, dts: np.ndarray) -> Belief:
        log = self.log
        log.enter(belief)
        b1, step = log.backend.predict_inputs(belief, process, us, dts)
        log.predicted(b1, step, us, dts)
        return b1

    def update(self, belief: Belief, model, z, R, gate=None):
        log = self.log
        log.enter(belief)
        result = self.inner.update(belief, model, z, R, gate)
        if result.accepted:
            log.updated(result.belief)
        return result

