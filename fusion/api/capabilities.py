"""Optional capabilities of components, one ``typing.Protocol`` each.

A component has a capability when its class defines the protocol's methods (structural typing: no base
class to inherit). The run loop and the filters find out ONCE, when a system is wired or a model is first
seen (:func:`has`, cached per class), and from then on call only what was declared: no ``hasattr`` in a
hot path. Renaming a method therefore switches a feature off; so a method one edit away from a
capability's name (``f_input`` for ``f_inputs``) is reported when the config is loaded
(:func:`near_misses`, a :class:`CapabilityWarning`), and ``fusion.testing.check_capabilities`` fails on it.

Shapes: ``n`` the state size, ``m`` a measurement's size, ``k`` a number of input samples, ``q`` the
noise size. Units SI, times in seconds (DESIGN.md).
"""
from __future__ import annotations

import inspect
from typing import Any, Callable, Protocol, Sequence, runtime_checkable

import numpy as np

from .messages import Event, Observation
from .state import Belief

__all__ = [
    # process models
    "Aligns", "ChecksStillness", "IntegratesInputRuns", "InputRunNoise", "LinearisesInputRuns", "NonAdditiveProcessNoise",
    "ReportsStepEvents", "HoldsInput",
    # measurement models
    "ChecksGeometry", "PositionFromFix", "NonAdditiveMeasurementNoise", "AlignsState", "InitialisesState",
    "UsesInput",
    "PseudoMeasurement",
    # filters
    "PredictsInputRuns",
    # gates
    "HasThreshold", "KeepsGateState",
    # solvers, decoders, models
    "ReadsBelief", "ReportsInfo",
    # sources, sinks
    "Opens", "Closes", "ReportsIdle", "ReportsStatus", "ReceivesEvents",
    "CAPABILITIES", "CapabilityWarning", "has", "capabilities_of", "near_misses",
]


# --------------------------------------------------------------------------- process models
@runtime_checkable
class Aligns(Protocol):
    """A process model that refines the initial belief from the mean input over a static start
    (``initial.align_s`` in the config), e.g. roll and pitch from gravity for an INS. Called once, when
    the static start is over, before any :class:`AlignsState` of the measurement models."""

    def align(self, x0: np.ndarray, P0: np.ndarray, u_mean: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x0 (n,), P0 (n, n)) refined; ``u_mean`` (input_dim,) the mean input over the static start."""
        ...


@runtime_checkable
class ChecksStillness(Protocol):
    """An :class:`Aligns` process model that can tell from the inputs of the alignment window whether the
    vehicle was static, as ``initial.align_s`` assumes (the ``ins``: the spread of the IMU samples against
    its noise densities). The scheduler calls it once, at the end of the window, before ``align``, which
    it then calls with ``still=`` the verdict and ``window=(us, ts)`` (a model with this capability
    accepts those keywords: with ``still=False`` it takes nothing from the window that only a
    static vehicle would give, e.g. the gyro bias). A window judged static also lets the scheduler combine
    the fixes of ``initial.from_sensor`` taken in it into the initial position
    (fusion.run.startup); one judged moving is a ``warning`` and in the summary's health."""

    def stillness(self, x0: np.ndarray, P0: np.ndarray, us: np.ndarray,
                  ts: np.ndarray) -> tuple[bool, str] | None:
        """``(still, why)`` for the window's input samples ``us`` (k, input_dim) at times ``ts`` (k,) (s), given
        the prior x0 (n,), P0 (n, n); ``why`` names the numbers. None: the model makes no static assumption
        for this window (nothing to test), or too few samples to judge."""
        ...


@runtime_checkable
class IntegratesInputRuns(Protocol):
    """A process model with a fast path for a run of input samples: the sigma-point filters' batched
    prediction (:class:`PredictsInputRuns`) calls it once with all points instead of ``k`` calls of f."""

    def f_inputs(self, x: np.ndarray, us: np.ndarray, dts: np.ndarray) -> np.ndarray:
        """States (..., n) after the inputs ``us`` (k, input_dim), sample j held over ``dts[j]`` s; must
        equal k calls of ``f`` to rounding."""
        ...


@runtime_checkable
class InputRunNoise(Protocol):
    """A process model that gives the process noise of a run of input samples (the INS: the noise of the
    interval propagated through the error dynamics). Without it the sigma-point filters predict a run
    sample by sample (one ``Q`` over the whole interval would leave out the early samples' noise carried
    through the later dynamics)."""

    def Q_inputs(self, x0: np.ndarray, x1: np.ndarray, us: np.ndarray, dts: np.ndarray) -> np.ndarray:
        """Q (n, n) of the run, from the mean before (x0, (n,)) and after (x1, (n,))."""
        ...


@runtime_checkable
class LinearisesInputRuns(Protocol):
    """A process model that linearises a run of input samples in one call: the EKF's batched prediction
    (``ekf.predict_inputs``) then propagates the covariance through the returned ``F_j``, ``Q_j`` instead
    of calling f, jacobian and Q once per sample. The same numbers as k per-sample predictions to
    rounding (the INS: its Jacobians vectorised over the run)."""

    def linearise_inputs(self, x: np.ndarray, us: np.ndarray, dts: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """``(x_k, F, Q)`` for the inputs ``us`` (k, input_dim), sample j held over ``dts[j]`` > 0 s, from
        the state x (n,): x_k (n,) the normalised mean after the run, F (k, n, n) and Q (k, n, n) the
        Jacobian and process noise of sample j at the (normalised) mean before it. None when the model
        has no run path for these inputs (the filter then predicts sample by sample)."""
        ...


@runtime_checkable
class NonAdditiveProcessNoise(Protocol):
    """A process model whose noise enters non-linearly; the augmented UKF (``augmented: true``) samples
    the noise w ~ N(0, Q) with the state and calls this instead of ``f(x, u, dt) + w``."""

    def f_with_noise(self, x: np.ndarray, w: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """States (..., n) from states x (..., n) and noise samples w (..., n)."""
        ...


@runtime_checkable
class ReportsStepEvents(Protocol):
    """A process model whose propagation can say something about a step (the ``ins`` clamps its
    norm-correction gain when eta dt >= 1). A pure function of the step, never a counter inside the model:
    the run calls it after each prediction with the sample intervals it integrated, counts the events'
    kinds with the filter's (``summary["filter_counters"]``) and puts them on the event stream."""

    def step_events(self, t: float, dts: np.ndarray) -> tuple[Event, ...]:
        """Events of the propagation over the intervals ``dts`` (k,) (s) that ended at time ``t`` (s)."""
        ...


@runtime_checkable
class HoldsInput(Protocol):
    """A process model that treats an input sample held past ``hold_after`` seconds (an input gap) other
    than a fresh one (the ``ins`` coasts, with the vehicle's motion as noise). A gap is usually cut into
    several predictions by the other sensors' messages; for each prediction that starts ``age`` seconds
    after the sample it holds, with ``age + dt > hold_after``, the run predicts with ``held(age)`` instead
    of the model itself, so the sample is integrated over ``hold_after`` since its own time, not since
    each prediction's start. ``hold_after`` None: the sample is always integrated (never called)."""

    hold_after: float | None

    def held(self, age: float) -> Any:
        """The model (a ProcessModel, same class, layout and input) for a prediction that starts ``age``
        s (> 0) after the input sample it holds."""
        ...


# --------------------------------------------------------------------------- measurement models
@runtime_checkable
class ChecksGeometry(Protocol):
    """A measurement model that can say whether the geometry is degenerate at the current estimate (the
    range model's GDOP / mirror check). Called after an accepted update, at most every 0.5 s of sensor
    time per sensor; the run reports the events when a warning starts, and a ``cleared`` event when it
    stops."""

    def check(self, belief: Belief, sensor: str) -> list[Event]:
        """Warnings (``Event(kind="warning")``) at ``belief``; empty when the geometry is fine."""
        ...


@runtime_checkable
class PositionFromFix(Protocol):
    """A position-like measurement model that can turn a fix into the state's position block (a receiver
    with a lever arm): used once, to initialise ``p`` from ``initial.from_sensor``'s first fix, and by a
    ``reset`` recovery. Without it the fix's first values are taken as ``p`` itself."""

    def position_from(self, z: np.ndarray, x: np.ndarray) -> np.ndarray:
        """The position block value (m,) (m) that makes ``h(x)`` equal the fix ``z`` (m,) at the attitude
        and other states of ``x`` (n,)."""
        ...


@runtime_checkable
class NonAdditiveMeasurementNoise(Protocol):
    """A measurement model whose noise enters non-linearly; the augmented UKF samples v ~ N(0, R) and
    calls this instead of ``h(x) + v``."""

    def h_with_noise(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Predicted measurements (..., m) from states (..., n) and noise samples (..., m)."""
        ...


@runtime_checkable
class AlignsState(Protocol):
    """A measurement model that initialises part of the state from its observations over the static start
    (``initial.align_s``), e.g. the attitude by TRIAD from the mean magnetometer sample and the mean
    specific force. The scheduler gathers the sensor's observations until the filter starts (instead of
    rejecting them) and calls this after the process model's own ``align`` (:class:`Aligns`)."""

    def align_state(self, x0: np.ndarray, P0: np.ndarray, u_mean: np.ndarray,
                    observations: Sequence[Observation], R: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """(x0, P0) refined; ``u_mean`` the mean input over the static start, ``R`` the sensor's noise.
        ``observations`` may be empty (the sensor sent nothing in the window): return (x0, P0) as they are,
        and refuse the later messages that need the alignment (RejectedMessage, with that reason)."""
        ...


@runtime_checkable
class InitialisesState(Protocol):
    """A measurement model whose observation replaces an uninformative prior instead of testing against it (the
    geometric solvers' initial fix: a prior of t 0 +- 1e5 s would refuse the fix of a log stamped in Unix
    time): the run updates with it without the sensor's gate. Declared by the class attribute
    ``initialises = True``; resolved once per class."""

    initialises: bool


@runtime_checkable
class UsesInput(Protocol):
    """A preprocessor or measurement model that needs the input at its messages' times (a TRIAD solver
    needs the accelerometer's specific force with each magnetometer sample). Before each of the sensor's
    messages the scheduler integrates the pending input samples up to the message and calls
    ``take_input(t, u)`` with the latest input sample (t its time; u None before the first)."""

    def take_input(self, t: float | None, u: np.ndarray | None) -> None: ...


@runtime_checkable
class PseudoMeasurement(Protocol):
    """A measurement model applied on a rule instead of on messages: ``rule = "after_predict"`` makes the
    scheduler update with ``pseudo_observation(belief)`` after every prediction (paper 002 eq. 9, the
    quaternion-norm pseudo-observation). Input samples are then integrated one by one (no batching), so
    the rule holds for every sample. The sensor's counters count the applications (``used``)."""

    rule: str

    def pseudo_observation(self, belief: Belief) -> Observation | None: ...


# --------------------------------------------------------------------------- filters and gates
@runtime_checkable
class PredictsInputRuns(Protocol):
    """A filter that integrates a run of input samples in one call. The scheduler then passes the input
    samples between two measurements together (at most 64); without it, one ``predict`` a sample."""

    def predict_inputs(self, belief: Belief, process: Any, us: np.ndarray, dts: np.ndarray) -> Belief:
        """The belief after the samples ``us`` (k, input_dim), sample j held over ``dts[j]`` s, in order."""
        ...


@runtime_checkable
class HasThreshold(Protocol):
    """A gate that can state its NIS threshold for a measurement of ``dim`` values (the chi-square
    quantile): used by recovery watches and the live view's test ratios."""

    def threshold(self, dim: int) -> float: ...


@runtime_checkable
class KeepsGateState(Protocol):
    """A gate whose decision depends on the measurements before (the ``reopening`` gate's integrator of
    the recent fit). The gate stays immutable: ``initial_state()`` returns the value its memory starts
    from (immutable: a tuple, a frozen dataclass), called once per run by the run's
    :class:`fusion.api.GateRun`; every ``check(nis, dim, state)`` then gets the current state and returns
    ``(GateDecision, next state)``. The run owns the state (and rewinds it with the belief on a replay),
    so two runs of one wired System decide alike. Without it a gate's ``check`` gets and returns None."""

    def initial_state(self) -> Any: ...


# --------------------------------------------------------------------------- solvers, decoders, models
@runtime_checkable
class ReportsInfo(Protocol):
    """Optional capability of a sensor's decoder, preprocessor or model: something the run's summary should
    say, e.g. the ``nmea`` decoder's local NED origin and where it came from. ``info()`` is called once when
    the run ends (on the run's own copy) and its dict written to ``summary["info"][sensor][kind]``."""

    def info(self) -> dict[str, Any]: ...


@runtime_checkable
class ReadsBelief(Protocol):
    """Optional capability of a sensor preprocessor: it reads the filter's current predicted belief.

    The run loop detects it once at wiring and calls ``bind_belief(belief_at)``. ``belief_at(t)`` returns
    the belief predicted to sensor time ``t`` (s) with the input samples received so far (the prediction the
    next update would make anyway; outputs it produces are emitted as usual), or None before the filter is
    initialised. Its ``t`` may be later than the one asked for when inputs past it were already integrated
    (no batching of inputs): the preprocessor then bridges the difference itself. Used by
    ``ols_trilateration`` to refer the ranges of a firing cycle to one time with the filter's velocity."""

    def bind_belief(self, belief_at: Callable[[float], Belief | None]) -> None: ...


# --------------------------------------------------------------------------- sources
@runtime_checkable
class Opens(Protocol):
    """A source that must be opened before ``lines()`` (a port, a socket); called once, by the run or the
    live view, and returns the opened source (usually itself)."""

    def open(self) -> Any: ...


@runtime_checkable
class Closes(Protocol):
    """A source with resources to release; ``close()`` may be called from another thread to end a
    blocked ``lines()``, and more than once."""

    def close(self) -> None: ...


@runtime_checkable
class ReportsIdle(Protocol):
    """A live source that calls ``on_idle()`` (when set, from the reading thread) after a read timed out
    with nothing received, so the live view can show what is pending."""

    on_idle: Callable[[], Any] | None


@runtime_checkable
class ReportsStatus(Protocol):
    """A reconnecting source that calls ``on_status(state, attempt, detail)`` (``reconnecting`` before
    attempt ``attempt``, ``connected``) from the reading thread."""

    on_status: Callable[[str, int, str], Any] | None


# --------------------------------------------------------------------------- sinks
@runtime_checkable
class ReceivesEvents(Protocol):
    """A sink (or any object given to a run as a sink) that takes the run's events too: ``on_event(event)``
    for every event, in the order they are released among the estimates (the ``Collect`` sink; a log)."""

    def on_event(self, event: Event) -> None: ...


# --------------------------------------------------------------------------- detection
#: Every capability protocol, by the member names it is detected by.
CAPABILITIES: tuple[type, ...] = (
    Aligns, ChecksStillness, IntegratesInputRuns, InputRunNoise, LinearisesInputRuns, NonAdditiveProcessNoise,
    ReportsStepEvents, HoldsInput, ChecksGeometry, PositionFromFix, NonAdditiveMeasurementNoise, AlignsState, UsesInput,
    PseudoMeasurement, InitialisesState,
    PredictsInputRuns, HasThreshold, KeepsGateState, ReportsInfo, ReadsBelief, Opens, Closes, ReportsIdle,
    ReportsStatus, ReceivesEvents,
)

_METHODS: dict[type, tuple[str, ...]] = {
    p: tuple(n for n, v in vars(p).items() if callable(v) and not n.startswith("_")) for p in CAPABILITIES}
_DATA: dict[type, tuple[str, ...]] = {
    p: tuple(n for n in getattr(p, "__annotations__", {}) if not n.startswith("_")) for p in CAPABILITIES}
_CACHE: dict[tuple[type, type], bool] = {}


def has(obj: Any, capability: type) -> bool:
    """Whether ``obj`` has ``capability``: its class defines the protocol's methods (cached per class, so
    this is a dict lookup after the first call) and the object has its data members."""
    cls = obj.__class__
    key = (cls, capability)
    hit = _CACHE.get(key)
    if hit is None:
        hit = _CACHE[key] = all(callable(getattr(cls, n, None)) for n in _METHODS[capability])
    if hit and _DATA[capability]:
        return all(hasattr(obj, n) for n in _DATA[capability])
    return hit


def capabilities_of(obj: Any) -> frozenset[type]:
    """Every capability protocol ``obj`` has."""
    return frozenset(p for p in CAPABILITIES if has(obj, p))


def _one_edit(a: str, b: str) -> bool:
    """True when ``a`` becomes ``b`` by one insertion, deletion, substitution or swap of neighbours."""
    if a == b or abs(len(a) - len(b)) > 1:
        return False
    if len(a) == len(b):
        diff = [i for i in range(len(a)) if a[i] != b[i]]
        return len(diff) == 1 or (len(diff) == 2 and diff[1] == diff[0] + 1
                                  and a[diff[0]] == b[diff[1]] and a[diff[1]] == b[diff[0]])
    short, long_ = (a, b) if len(a) < len(b) else (b, a)
    i = 0
    while i < len(short) and short[i] == long_[i]:
        i += 1
    return short[i:] == long_[i + 1:]


_NAMES = sorted({n for p in CAPABILITIES for n in _METHODS[p] + _DATA[p]})


def near_misses(cls: type) -> list[str]:
    """Public methods of ``cls`` (its own and inherited, outside fusion.api) one edit away from a capability
    member it does not define: ``"file:line: FluxModel.f_input looks like capability member 'f_inputs'
    (IntegratesInputRuns) but is not it"``; empty when none."""
    out = []
    own = set(dir(cls))
    for name in dir(cls):
        if name.startswith("_") or name in _NAMES:
            continue
        for target in _NAMES:
            if target not in own and _one_edit(name, target):
                fn = inspect.unwrap(getattr(cls, name))
                if not callable(fn):
                    continue
                where = ""
                try:
                    where = f"{inspect.getsourcefile(fn)}:{inspect.getsourcelines(fn)[1]}: "
                except (OSError, TypeError):
                    pass
                protos = ", ".join(p.__name__ for p in CAPABILITIES if target in _METHODS[p] + _DATA[p])
                out.append(f"{where}{cls.__qualname__}.{name} looks like capability member {target!r} "
                           f"({protos}) but is not it: the feature stays off")
    return out


class CapabilityWarning(UserWarning):
    """A component method whose name is one edit away from a capability (see :func:`near_misses`)."""
