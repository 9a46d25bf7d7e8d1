"""What a gate decides and how a run keeps a gate's memory: :class:`GateDecision` and :class:`GateRun`.

A gate (``fusion.api.Gate``) is an immutable object: ``check(nis, dim, state)`` returns its decision as a
value with the gate's next state, and counts nothing. A gate whose decision depends on the past (the
``reopening`` gate's integrator) declares :class:`fusion.api.KeepsGateState`: ``initial_state()`` gives
the value its memory starts from, and each ``check`` returns the next one. The run owns that state: the
scheduler makes one :class:`GateRun` per gated sensor, hands it to the filter's ``update`` as its
``gate`` (a filter only calls ``accept(nis, dim) -> bool``), and counts the decisions in it. So a wired
``System`` is never changed by a run, and running it twice gives identical results.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from .capabilities import KeepsGateState, has

if TYPE_CHECKING:
    from .components import Gate

__all__ = ["GateDecision", "GateRun"]


@dataclass(frozen=True)
class GateDecision:
    """One gate decision on one measurement.

    ``accepted``: the measurement may update the belief (a NaN NIS never is);
    ``threshold``: the NIS threshold (dimensionless, chi-square) it was held against, ``inf`` when the gate
    let everything through (an open ``reopening`` gate);
    ``reasons``: what else happened, each a counter name the run adds 1 to (``opened``: the gate opened on
    this measurement; ``closed``; ``accepted_open``: accepted because the gate is open). Every decision is
    also counted as ``checked``, and a refused one as ``rejected``."""

    accepted: bool
    threshold: float
    reasons: tuple[str, ...] = ()


class GateRun:
    """One run's use of one gate: the gate's state (:class:`fusion.api.KeepsGateState`, else None), its
    last decision and the counts of its decisions (``checked``, ``rejected`` and each decision's
    ``reasons``). Owned by the run that made it (the scheduler makes one per gated sensor; a test can
    make its own); what a filter's ``update`` receives as ``gate``.

    ``state`` is a value (a gate never changes it in place), so a snapshot of it is the value itself
    (``late_policy: replay`` rewinds it with the belief)."""

    __slots__ = ("gate", "state", "last", "counters")

    def __init__(self, gate: "Gate"):
        self.gate = gate
        self.state: Any = gate.initial_state() if has(gate, KeepsGateState) else None  # type: ignore[attr-defined]
        self.last: GateDecision | None = None
        self.counters: Counter = Counter()

    def accept(self, nis: float, dim: int) -> bool:
        """The gate's decision on a measurement of ``dim`` values with NIS ``nis``; the state moves on and
        the decision is counted."""
        decision, self.state = self.gate.check(nis, dim, self.state)
        self.last = decision
        c = self.counters
        c["checked"] += 1
        if not decision.accepted:
            c["rejected"] += 1
        for reason in decision.reasons:
            c[reason] += 1
        return decision.accepted

    def __repr__(self) -> str:
        return f"<GateRun {self.gate.name} state={self.state!r}>"
