"""The interface of a sensor simulator (a ``simulator`` plugin), and what it is given.

A simulator is a ``fusion.api.Simulator`` built as ``cls(params, context)`` from a scenario's sensor entry
(``type: NAME`` selects it by registry name, the other keys are its ``Params``). ``fusion simulate`` then
calls ``fields()``, ``header()``, ``rate_hz()`` and ``simulate(sim)``; ``truth_fields()`` and
``truth(t)`` add the true values of its own error states (e.g. IMU biases) to the truth lines.

A third-party simulator subclasses ``SensorSimulator`` and registers itself with
``registry.add(MySimulator)`` in its ``fusion_register_components`` hook.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Sequence

import numpy as np
from pydantic import Field

from fusion.api import Params, Simulator
from fusion.simulate.kinematics import Kinematics


@dataclass
class SimContext:
    """What a simulator gets: the trajectory (``kinematics(t)``), the scenario's beacons (name -> (3,) m;
    2-D beacons have z = 0), ``dim`` (2 or 3), gravity (m/s^2), geodetic ``origin`` (lat deg, lon deg, alt
    m) or None, ``start_utc`` (datetime of t = 0), the scenario ``duration`` (s), ``noise`` (False: every
    value exact, no biases, no outliers) and this sensor's own random generator ``rng``."""

    trajectory: Any
    beacons: dict[str, np.ndarray]
    dim: int
    gravity: float
    duration: float
    noise: bool
    rng: np.random.Generator
    origin: tuple[float, float, float] | None = None
    start_utc: Any = None
    extra: dict[str, Any] = field(default_factory=dict)

    def kinematics(self, t: np.ndarray) -> Kinematics:
        return self.trajectory.sample(np.asarray(t, float))


@dataclass
class SensorOutput:
    """Messages of one sensor: times (N,) and one tuple of values (floats or labels) per message."""

    t: np.ndarray
    values: Sequence[Sequence[Any]]


class SimParams(Params):
    """Parameters every simulator has."""

    type: str = Field(description="simulator name (registry)")
    precision: int | None = Field(None, ge=1, le=12, description="decimals of the values (default: scenario)")


class SensorSimulator(Simulator):
    """Base class of the built-in simulators (see the module docstring)."""

    Params: ClassVar[type[SimParams]] = SimParams

    def fields(self, sim: SimContext) -> tuple[str, ...]:
        """Column names after ``t,sensor`` (the ``# fields`` line)."""
        raise NotImplementedError

    def header(self, sim: SimContext) -> list[str]:
        """Extra metadata lines (without ``# ``), e.g. ``imu rate_hz: 100``."""
        return []

    def rate_hz(self) -> float:
        """Nominal message rate (Hz): the truth rate is the highest of these."""
        return float(getattr(self.params, "rate_hz", 0.0) or 0.0)

    def simulate(self, sim: SimContext) -> SensorOutput:
        raise NotImplementedError

    def truth_fields(self) -> tuple[str, ...]:
        """Names of the true error states this sensor adds to the truth lines (e.g. bax ... bwz)."""
        return ()

    def truth(self, t: np.ndarray) -> np.ndarray:
        """True values (N, len(truth_fields())) at times t (called after simulate)."""
        return np.zeros((len(t), 0))


def sample_times(rate_hz: float, duration: float, offset: float = 0.0) -> np.ndarray:
    """``offset + k / rate`` for every k with a time in [0, duration] (computed from integers, no drift)."""
    n = int(np.floor((duration - offset) * rate_hz + 1e-9)) + 1
    return offset + np.arange(max(n, 0)) / rate_hz
