"""What components exchange during a run: messages, observations, fixes, update results, events, estimates."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from fusion.errors import MalformedMessage

from .state import Belief

if TYPE_CHECKING:
    from .components import MeasurementModel

__all__ = ["MAX_MAGNITUDE", "Message", "Observation", "Fix", "UpdateResult", "Event", "Estimate"]

#: Largest |value| a measurement may hold: beyond it its square (in an innovation's NIS, a range's
#: geometry, a Gaussian update) overflows float64 (1.8e308), so no filter can use it: malformed.
MAX_MAGNITUDE = 1e150


class Message(NamedTuple):
    """One timestamped sensor message (immutable).

    ``values`` holds the fields after ``t,sensor``: floats, or strings for labels (a beacon name) and raw
    payloads (an NMEA sentence). ``line`` is the 1-based line number in the source, for error messages.
    A NamedTuple rather than a frozen dataclass: one is built per line, and this builds in half the time.
    """

    t: float
    sensor: str
    values: tuple[Any, ...]
    line: int | None = None

    def floats(self) -> np.ndarray:
        """The values as a float64 array (raises MalformedMessage when one is not a number)."""
        try:
            return np.array(self.values, dtype=float)
        except (TypeError, ValueError):
            raise MalformedMessage(f"expected numbers, got {self.values!r}") from None


@dataclass(frozen=True)
class Observation:
    """A measurement ready for a filter update: ``z`` (m,), the model to predict it (possibly bound to the
    message, e.g. a range model bound to beacon B2) and, optionally, its own covariance ``R`` (m, m)
    (a solver's fix carries one); ``None`` means the sensor's configured R."""

    t: float
    z: np.ndarray
    model: "MeasurementModel"
    R: np.ndarray | None = None


def _empty() -> np.ndarray:
    return np.zeros(0)


@dataclass(frozen=True)
class Fix:
    """A solver's single-shot estimate (a trilateration's position, a TRIAD attitude, a geometric
    initialiser's state), as it travels from a sensor's preprocessor to the sensor's measurement model
    (``observe(fix)``): typed, no float-array wire protocol between plugins.

    ``t`` (s): the sensor time it is stamped at (the message that closed the solver's cycle);
    ``value`` (m,): what was solved for, in the model's units and frame (a position: m, NED; the paper 003
    initialiser's ``[x y z t]``: m and the firing time, s); empty for an attitude-only fix;
    ``cov`` (m, m): its covariance, or None (the sensor's configured noise applies);
    ``age`` (s, >= 0): the value is of ``age`` seconds before ``t`` (a cycle's mean range time);
    ``used``: the beacons (or other sources) it was solved from; ``sensor`` and ``line``: the sensor and
    source line of the closing message, for events and error messages;
    ``attitude`` (4,): an attitude solved for, the unit quaternion C_b^n (Hamilton, scalar first), or None;
    ``attitude_cov`` (3, 3): the covariance (rad^2) of its error as a navigation-frame rotation vector
    ``d theta`` (``q_fix = exp(d theta / 2) (x) q_true``), or None; uncorrelated with ``value``."""

    t: float
    value: np.ndarray = field(default_factory=_empty)
    cov: np.ndarray | None = None
    age: float = 0.0
    used: tuple[str, ...] = ()
    sensor: str = ""
    line: int | None = None
    attitude: np.ndarray | None = None
    attitude_cov: np.ndarray | None = None


@dataclass(frozen=True, init=False)
class UpdateResult:
    """What a filter update returns. ``belief`` is the input belief when ``accepted`` is False.
    (Fields written directly by the constructor, as for Belief: one is built per update.)"""

    belief: Belief
    innovation: np.ndarray
    S: np.ndarray
    nis: float
    accepted: bool
    #: What the filter had to report on the way (a repaired covariance, a failed downdate), for the run's
    #: event stream and counters; the filter itself keeps nothing.
    events: tuple["Event", ...] = ()
    #: Linearisations done (the IEKF's Gauss-Newton iterations; 1 for the other filters).
    iterations: int = 1

    def __init__(self, belief: Belief, innovation: np.ndarray, S: np.ndarray, nis: float, accepted: bool,
                 events: tuple["Event", ...] = (), iterations: int = 1):
        self.__dict__.update(belief=belief, innovation=innovation, S=S, nis=nis, accepted=accepted,
                             events=events, iterations=iterations)


@dataclass(frozen=True)
class Event:
    """Something worth reporting: ``kind`` in e.g. ``malformed``, ``late``, ``rejected``, ``gap``,
    ``not_positive_definite``, ``no_fix``, ``warning``. ``sensor`` may be None."""

    t: float
    kind: str
    sensor: str | None
    detail: str = ""


@dataclass(frozen=True)
class Estimate:
    """A belief emitted by the scheduler. ``reason`` is ``update`` (after a measurement from ``sensor``)
    or ``output`` (a fixed-rate output by prediction). ``update`` holds the filter's UpdateResult, if any."""

    t: float
    belief: Belief
    reason: str
    sensor: str | None = None
    update: UpdateResult | None = None
