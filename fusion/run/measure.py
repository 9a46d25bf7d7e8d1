"""The measurement step: one observation fused into a belief already predicted to its time, as a function of
its arguments that returns an :class:`Outcome` and changes nothing of the loop's. The per-run state it is
given (the sensor's gate run and lock-out watch) is the run's, as the gate state is.

What the loop does with an outcome: tally its ``results`` (fusion.run.tally), hand on its ``events`` (a
recovery's ``reset``), lose the message when ``failure`` is set (a plugin's fault, or raise it: the filter's),
count ``counts`` on the sensor, and take ``belief``."""
from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from fusion.api import Belief, Event, FusionError, Observation, UpdateResult
from fusion.recovery import recover
from fusion.run.plan import SensorPlan, ungated

__all__ = ["Outcome", "Updated", "measure", "finite"]


class Updated(NamedTuple):
    """An update tried: its time (s), sensor, NIS, dimension and whether it was accepted. Travels once, from the
    measurement step to the run's statistics (not to the sinks)."""

    t: float
    sensor: str
    nis: float
    dim: int
    accepted: bool


class Outcome(NamedTuple):
    """What one measurement step made of an observation.

    ``belief``: the belief to go on with (the given one when nothing was fused); ``result``: the last update
    tried (None when it raised); ``results``: every update tried, in order (a recovery tries two); ``events``:
    what the step reports before the filter's events (a ``reset``); ``counts``: the sensor's counters to add
    (``used`` or ``rejected``; none when the update raised); ``verdict``: ``used``, ``rejected`` (outside the
    gate), ``nonfinite`` (refused: the update is not finite) or ``failed``; ``failure``: the exception of a
    failed update; ``resets``: recoveries made; ``update_s``: s spent in the first update."""

    belief: Belief
    result: UpdateResult | None
    results: tuple[UpdateResult, ...] = ()
    events: tuple[Event, ...] = ()
    counts: dict[str, int] = {}   # never changed: the counts of a failed step
    verdict: str = "failed"
    failure: Exception | None = None
    resets: int = 0
    update_s: float = 0.0


def measure(filt, belief: Belief, obs: Observation, R: np.ndarray, plan: SensorPlan, layout,
            watch_on: bool = True) -> Outcome:
    """Fuse ``obs`` (at ``belief.t``) with noise ``R`` through ``filt.update`` with the sensor's gate (none for
    a model that initialises the state, fusion.api.InitialisesState). A lock-out of the sensor (its
    ``plan.watch``, when ``watch_on``: not in a replay's re-run) recovers the belief from the observation
    (fusion.recovery) and fuses it again. An exception of the filter's update is the outcome's ``failure``;
    a FusionError is raised (the input cannot go on)."""
    gate = None if ungated(obs.model) else plan.gate
    t0 = time.perf_counter()
    try:
        result = filt.update(belief, obs.model, obs.z, R, gate)
    except FusionError:
        raise
    except Exception as exc:  # a model's h or jacobian that raises, or returns the wrong shape
        return Outcome(belief, None, failure=exc)
    update_s = time.perf_counter() - t0
    results = (result,)
    events: tuple[Event, ...] = ()
    resets = 0
    watch = plan.watch
    if watch is not None and watch_on:
        th = plan.threshold(len(obs.z)) if plan.threshold is not None else None
        if watch.update(obs.t, result.accepted, result.nis, th, result.innovation, result.S, obs.model):
            watch.clear()
            resets = 1
            belief, event = recover(plan.runtime.recovery, belief, layout, obs, R, filt, plan.name)
            events = (event,)
            try:
                result = filt.update(belief, obs.model, obs.z, R, plan.gate)
            except FusionError:
                raise
            except Exception as exc:
                return Outcome(belief, None, results, events, failure=exc, resets=resets, update_s=update_s)
            results += (result,)
    if result.accepted and not finite(result.nis, result.belief) and finite(0.0, belief):
        # never a NaN propagated silently: a model whose prediction (or Jacobian) is not finite at this state
        # would make the belief NaN for the rest of the run, gate or no gate: refused
        return Outcome(belief, result, results, events, {"rejected": 1}, "nonfinite", resets=resets, update_s=update_s)
    if result.accepted:
        return Outcome(result.belief, result, results, events, {"used": 1}, "used", resets=resets, update_s=update_s)
    return Outcome(belief, result, results, events, {"rejected": 1}, "rejected", resets=resets, update_s=update_s)


def finite(nis: float | None, belief: Belief | None) -> bool:
    """NIS, mean and covariance (or its factor) all finite (one sum each)."""
    if belief is None:
        return True
    m = belief.S if belief.S is not None else belief.P
    total = (0.0 if nis is None else float(nis)) + float(belief.x.sum()) + (float(m.sum()) if m is not None else 0.0)
    return total - total == 0.0
