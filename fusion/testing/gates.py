"""The gate contract (fusion.api.Gate), for plugin authors and the built-ins alike: :func:`check_gate`."""
from __future__ import annotations

import copy
from typing import Any, Mapping

import numpy as np

from fusion.api import BuildContext, Gate, GateDecision, GateRun, HasThreshold, KeepsGateState, has

from .models import check_component

__all__ = ["check_gate"]


def _vars(obj: Any) -> dict:
    """A copy of an object's attributes but its build context (what a decision must not change)."""
    return {k: copy.deepcopy(v) for k, v in vars(obj).items() if k != "context"}


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        np.array_equal(a[k], b[k]) if isinstance(a[k], np.ndarray) else a[k] == b[k] for k in a)


def check_gate(cls: type[Gate], params: Mapping[str, Any] | None = None, *, context: BuildContext | None = None,
               n: int = 400, seed: int = 0) -> dict[str, int]:
    """The gate contract: :func:`check_component`; ``check(nis, dim, state)`` returns a
    ``(GateDecision, state)`` pair whose threshold is a number > 0 (``inf`` allowed: an open gate); a NaN
    NIS is never accepted; the gate object is unchanged by ``n`` decisions (it is immutable: counts and
    memory belong to the run's GateRun); ``check`` leaves the state it is given as it was (a new state is
    returned; a replay rewinds to old ones); two GateRuns of one gate, fed the same NIS, decide and count
    alike (its state is a value, not shared); a gate without KeepsGateState answers ``accept`` as
    ``check``; ``threshold(dim)`` (HasThreshold) is > 0 for dim 1-6. Returns the counts of the first run."""
    check_component(cls)
    who = cls.__qualname__
    gate = cls(cls.Params(**dict(params or {})), context)
    before = _vars(gate)
    rng = np.random.default_rng(seed)
    dims = rng.integers(1, 7, n)
    nis = rng.chisquare(dims) * np.where(rng.random(n) < 0.3, 30.0, 1.0)   # consistent, and 30 % outliers
    nis[rng.random(n) < 0.05] = np.nan
    state = gate.initial_state() if has(gate, KeepsGateState) else None
    for v, m in zip(nis[:20], dims[:20]):
        kept = copy.deepcopy(state)
        out = gate.check(float(v), int(m), state)
        assert _same({"s": state}, {"s": kept}), (f"{who}.check changed the state it was given: a state is a "
                                                  "value (the run keeps old ones to rewind a replay)")
        assert isinstance(out, tuple) and len(out) == 2 and isinstance(out[0], GateDecision), \
            f"{who}.check must return (GateDecision, state), got {out!r}"
        d, state = out
        assert isinstance(d.threshold, float) and d.threshold > 0, f"{who}: threshold {d.threshold!r} is not > 0"
        assert not (v != v and d.accepted), f"{who}: a NaN NIS was accepted"
        if not has(gate, KeepsGateState):
            assert state is None, f"{who}: a gate without KeepsGateState must return state None, got {state!r}"
            assert gate.accept(float(v), int(m)) is d.accepted, f"{who}: accept() disagrees with check()"
    a, b = GateRun(gate), GateRun(gate)
    first = [a.accept(float(v), int(m)) for v, m in zip(nis, dims)]
    second = [b.accept(float(v), int(m)) for v, m in zip(nis, dims)]
    assert first == second and a.counters == b.counters, f"{who}: two runs of one gate decided differently"
    assert not any(ok for ok, v in zip(first, nis) if v != v), f"{who}: a NaN NIS was accepted"
    assert _same(_vars(gate), before), (f"{who}: the gate changed while deciding (attributes "
                                        f"{sorted(set(vars(gate)) - {'context'})}): a gate is immutable")
    if has(gate, HasThreshold):
        for m in range(1, 7):
            th = gate.threshold(m)
            assert th > 0, f"{who}: threshold({m}) = {th!r} is not > 0"
    return dict(a.counters)
