"""What the loop calls for each sensor, resolved once when a run is made: a frozen :class:`SensorPlan` of bound
callables per sensor (None where a component lacks the capability), so no message is met with a ``getattr``
or a capability test. Models met only at run time (the model an Observation names, a solver's fix model) are
resolved once per class (:func:`ungated`)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from fusion.api import (AlignsState, ChecksGeometry, HasThreshold, InitialisesState, PseudoMeasurement, UsesInput,
                        has)
from fusion.config import SensorRuntime
from fusion.recovery import LockoutWatch
from fusion.run.checks import CheckedGateRun

__all__ = ["SensorPlan", "plan_sensor", "ungated", "geometry_check"]


@dataclass(frozen=True)
class SensorPlan:
    """One sensor's parts for the run. ``runtime``: its wired parts and counters (the run's copy); ``gate``: its
    gate's per-run state (fusion.api.GateRun) or None; ``watch``: its lock-out watch (fusion.recovery) or None;
    ``threshold(dim)``: the gate's NIS threshold or None; ``check(belief, sensor)``: the model's geometry
    check or None; ``input_users``: ``take_input(t, u)`` of the components that read the input at its
    messages; ``drainers``: ``take_events()`` of the components that queue events; ``aligns``: its model
    aligns part of the state over the static start (``initial.align_s`` set); ``pseudo``: the model's
    after-predict ``pseudo_observation(belief)`` or None."""

    name: str
    runtime: SensorRuntime
    gate: CheckedGateRun | None
    watch: LockoutWatch | None
    threshold: Callable[[int], float] | None
    check: Callable | None
    input_users: tuple[Callable, ...]
    drainers: tuple[Callable, ...]
    aligns: bool
    pseudo: Callable | None


def plan_sensor(sensor: SensorRuntime, align_s: float) -> SensorPlan:
    """The plan of ``sensor`` (the run's own copy of it)."""
    model, parts = sensor.model, (sensor.preprocessor, sensor.decoder, sensor.model)
    pseudo = None
    if isinstance(model, PseudoMeasurement) and model.rule == "after_predict":
        pseudo = model.pseudo_observation
    return SensorPlan(
        name=sensor.name, runtime=sensor,
        gate=CheckedGateRun(sensor.gate) if sensor.gate is not None else None,
        watch=LockoutWatch(sensor.recovery) if sensor.recovery is not None else None,
        threshold=sensor.gate.threshold if has(sensor.gate, HasThreshold) else None,
        check=model.check if model is not None and has(model, ChecksGeometry) else None,
        input_users=tuple(c.take_input for c in (sensor.preprocessor, model) if isinstance(c, UsesInput)),
        drainers=tuple(c.take_events for c in parts if c is not None and callable(getattr(c, "take_events", None))),
        aligns=bool(align_s) and isinstance(model, AlignsState),
        pseudo=pseudo)


_UNGATED: dict[type, bool] = {}


def ungated(model: Any) -> bool:
    """A model whose observation replaces an uninformative prior (fusion.api.InitialisesState: the geometric
    solvers' initial fix), updated without the sensor's gate; resolved once per class."""
    cls = model.__class__
    hit = _UNGATED.get(cls)
    if hit is None:
        hit = _UNGATED[cls] = has(model, InitialisesState) and bool(getattr(cls, "initialises", False))
    return hit


def geometry_check(model: Any) -> Callable | None:
    """The ``check`` of a model met at run time (ChecksGeometry, resolved per class), or None."""
    return model.check if has(model, ChecksGeometry) else None
