"""The types plugins implement and exchange: the whole API a plugin author needs, with fusion.hookspecs.

Conventions (DESIGN.md): SI units; NED navigation frame, FRD body frame; quaternions Hamilton,
scalar first ``[w x y z]``, body-to-navigation (C_b^n); angles in radians; time in seconds (float64).

Shapes: a state is ``(..., n)``; process and measurement functions are vectorised over the leading
axes, so a sigma-point filter calls them once per step with all ``2n+1`` points.

Modules: ``state`` (StateLayout, Belief), ``messages`` (Message, Observation, Fix, UpdateResult, Event,
Estimate), ``gates`` (GateDecision, GateRun: a gate's verdict, and its state and counts in one run),
``components`` (the bases of every kind), ``capabilities`` (the optional capabilities, one Protocol each),
``importing`` (the importer kind); the errors live in fusion.errors. Everything is importable from
``fusion.api`` itself, also ``OutputFile`` (fusion.outputs: how a sink writes its file, atomically, in
place for a FIFO or device, errors as one line; docs/writing-plugins.md, "A sink").
"""
from __future__ import annotations

from fusion.errors import ConfigError, FusionError, InputError, MalformedMessage, RejectedMessage
from fusion.kinds import KINDS

from .capabilities import (CAPABILITIES, Aligns, AlignsState, InitialisesState, ChecksStillness, CapabilityWarning, ChecksGeometry,
                           Closes, HasThreshold, HoldsInput, InputRunNoise, IntegratesInputRuns, KeepsGateState,
                           LinearisesInputRuns,
                           NonAdditiveMeasurementNoise, NonAdditiveProcessNoise, Opens, PositionFromFix,
                           PredictsInputRuns, PseudoMeasurement, ReadsBelief, ReceivesEvents, ReportsIdle,
                           ReportsInfo, ReportsStatus, ReportsStepEvents, UsesInput, capabilities_of, has,
                           near_misses)
from .components import (BuildContext, Component, Decoder, Filter, Gate, MeasurementModel, Params,
                         ProcessModel, Simulator, Sink, Solver, Source)
from .gates import GateDecision, GateRun
from .importing import ImportedLog, Importer, ImportRequest, Stream
from .messages import MAX_MAGNITUDE, Estimate, Event, Fix, Message, Observation, UpdateResult
from .state import Belief, Block, BlockKind, StateLayout

#: The simulator kit (``fusion.simulate.base``), importable from here too; loaded on first use, so that
#: importing fusion.api stays cheap.
_SIMULATION = ("SensorSimulator", "SimContext", "SensorOutput", "SimParams", "sample_times")


#: The output helpers (``fusion.outputs``) a sink writes its file with; loaded on first use (start-up).
_OUTPUTS = ("OutputFile", "StdoutClosed", "is_stream")


def __getattr__(name: str):
    if name in _SIMULATION:
        from fusion.simulate import base

        return getattr(base, name)
    if name in _OUTPUTS:
        from fusion import outputs

        return getattr(outputs, name)
    raise AttributeError(f"module 'fusion.api' has no attribute {name!r}")


__all__ = [
    "Block", "BlockKind", "StateLayout", "Belief", "Message", "Observation", "Fix", "UpdateResult", "Event",
    "Estimate", "Params", "BuildContext", "Component", "ProcessModel", "MeasurementModel",
    "Filter", "Gate", "GateDecision", "GateRun", "Decoder", "Solver", "Source", "Sink", "Simulator", "FusionError",
    "ConfigError", "InputError", "MalformedMessage", "RejectedMessage", "KINDS", "MAX_MAGNITUDE",
    "Importer", "ImportRequest", "Stream", "ImportedLog",
    # optional capabilities (fusion.api.capabilities)
    "Aligns", "ChecksStillness", "IntegratesInputRuns", "InputRunNoise", "LinearisesInputRuns", "NonAdditiveProcessNoise",
    "ReportsStepEvents", "HoldsInput", "ChecksGeometry", "PositionFromFix", "NonAdditiveMeasurementNoise", "AlignsState",
    "UsesInput", "InitialisesState", "PseudoMeasurement", "PredictsInputRuns", "HasThreshold", "KeepsGateState", "ReadsBelief",
    "ReportsInfo", "Opens", "Closes", "ReportsIdle", "ReportsStatus", "ReceivesEvents", "CAPABILITIES",
    "CapabilityWarning", "has", "capabilities_of", "near_misses",
    *_SIMULATION, *_OUTPUTS,
]
