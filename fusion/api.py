"""The types plugins implement and exchange: the whole API a plugin author needs, with fusion.hookspecs.

Conventions (DESIGN.md): SI units; NED navigation frame, FRD body frame; quaternions Hamilton,
scalar first ``[w x y z]``, body-to-navigation (C_b^n); angles in radians; time in seconds (float64).

Shapes: a state is ``(..., n)``; process and measurement functions are vectorised over the leading
axes, so a sigma-point filter calls them once per step with all ``2n+1`` points.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable, ClassVar, Literal, Mapping, NamedTuple, Protocol, Sequence, runtime_checkable

import numpy as np
from pydantic import BaseModel, ConfigDict

__all__ = [
    "Block", "StateLayout", "Belief", "Message", "Observation", "UpdateResult", "Event",
    "Estimate", "Params", "BuildContext", "Component", "ProcessModel", "MeasurementModel",
    "Filter", "Gate", "Decoder", "Solver", "Source", "Sink", "Simulator", "FusionError",
    "ConfigError", "InputError", "MalformedMessage", "RejectedMessage", "KINDS", "ReadsBelief", "ReportsInfo", "MAX_MAGNITUDE",
    "Importer", "ImportRequest", "Stream", "ImportedLog",
    "AlignsState", "UsesInput", "PseudoMeasurement",
]

#: Largest |value| a measurement may hold: beyond it its square (in an innovation's NIS, a range's
#: geometry, a Gaussian update) overflows float64 (1.8e308), so no filter can use it: malformed.
MAX_MAGNITUDE = 1e150

from fusion.kinds import KINDS  # noqa: E402

BlockKind = Literal["vector", "quaternion", "angle"]


# --------------------------------------------------------------------------- errors
# Defined in fusion.errors (no numpy or pydantic there, so the CLI can report them before importing
# either); the same classes, re-exported here as part of the plugin API.
from fusion.errors import ConfigError, FusionError, InputError, MalformedMessage, RejectedMessage  # noqa: E402


# --------------------------------------------------------------------------- state layout
_AXES = {"vector": "xyz", "quaternion": "wxyz"}


@dataclass(frozen=True)
class Block:
    """A named block of the state: ``p:3`` (vector), ``q:4`` (quaternion), ``psi:1`` (angle)."""

    name: str
    size: int
    kind: BlockKind = "vector"

    def element_names(self) -> tuple[str, ...]:
        """Names of the elements: ``px py pz`` (vector <= 3), ``qw qx qy qz`` (quaternion), else ``b0 b1 ..``."""
        if self.kind == "quaternion":
            return tuple(self.name + a for a in "wxyz")
        if self.kind == "vector" and self.size <= 3:
            return tuple(self.name + a for a in "xyz"[: self.size])
        if self.size == 1:
            return (self.name,)
        return tuple(f"{self.name}{i}" for i in range(self.size))


class StateLayout:
    """Ordered named blocks; everything outside a model addresses the state by block name.

    >>> lay = StateLayout.parse("p:3 v:3 q:4:quaternion")
    >>> lay.n, lay["v"], lay.names[:4]
    (10, slice(3, 6, None), ('px', 'py', 'pz', 'vx'))
    """

    def __init__(self, blocks: Sequence[Block]):
        self.blocks: tuple[Block, ...] = tuple(blocks)
        names = [b.name for b in self.blocks]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate block names in state layout: {names}")
        self._slices: dict[str, slice] = {}
        i = 0
        for b in self.blocks:
            self._slices[b.name] = slice(i, i + b.size)
            i += b.size
        self.n: int = i
        self.names: tuple[str, ...] = tuple(e for b in self.blocks for e in b.element_names())

    @classmethod
    def parse(cls, spec: str) -> "StateLayout":
        """Parse ``"name:size[:kind] ..."``, e.g. ``"p:3 v:3 q:4:quaternion ba:3 bw:3"``."""
        blocks = []
        for tok in spec.split():
            parts = tok.split(":")
            kind = parts[2] if len(parts) > 2 else ("quaternion" if parts[0] == "q" and parts[1] == "4" else "vector")
            blocks.append(Block(parts[0], int(parts[1]), kind))  # type: ignore[arg-type]
        return cls(blocks)

    def __getitem__(self, name: str) -> slice:
        try:
            return self._slices[name]
        except KeyError:
            raise KeyError(f"state has no block {name!r}; blocks are {list(self._slices)}") from None

    def __contains__(self, name: str) -> bool:
        return name in self._slices

    def __len__(self) -> int:
        return self.n

    def __eq__(self, other: object) -> bool:
        return isinstance(other, StateLayout) and self.blocks == other.blocks

    def __hash__(self) -> int:
        return hash(self.blocks)

    def __repr__(self) -> str:
        return "StateLayout(" + " ".join(f"{b.name}:{b.size}:{b.kind}" for b in self.blocks) + ")"

    def block(self, name: str) -> Block:
        for b in self.blocks:
            if b.name == name:
                return b
        raise KeyError(f"state has no block {name!r}; blocks are {list(self._slices)}")

    def element_index(self, element: str) -> int:
        """Index of a named element (``"vy"``)."""
        try:
            return self.names.index(element)
        except ValueError:
            raise KeyError(f"state has no element {element!r}; elements are {list(self.names)}") from None

    def vector(self, values: Mapping[str, Any], default: float = 0.0) -> np.ndarray:
        """Assemble a full state vector from ``{block: values}`` (scalar broadcast to the block)."""
        x = np.full(self.n, default, dtype=float)
        for name, val in values.items():
            sl = self[name]
            arr = np.broadcast_to(np.asarray(val, dtype=float), (sl.stop - sl.start,))
            x[sl] = arr
        return x


# --------------------------------------------------------------------------- data
@dataclass(frozen=True, init=False)
class Belief:
    """Gaussian belief at time ``t``: mean ``x`` (n,) and either covariance ``P`` (n, n) or its
    lower Cholesky factor ``S`` (P = S S^T, used by the square-root UKF). Immutable: filters return new ones.

    The constructor writes the fields directly: a frozen dataclass's own ``__init__`` (one
    ``object.__setattr__`` a field) costs ~2 us, and filters build one or two beliefs a step."""

    t: float
    x: np.ndarray
    P: np.ndarray | None = None
    S: np.ndarray | None = None

    def __init__(self, t: float, x: np.ndarray, P: np.ndarray | None = None, S: np.ndarray | None = None):
        if P is None and S is None:
            raise ValueError("a Belief needs P or S")
        self.__dict__.update(t=t, x=x, P=P, S=S)

    @property
    def cov(self) -> np.ndarray:
        """The covariance P (computed from S when the belief is square-root)."""
        if self.P is not None:
            return self.P
        return self.S @ self.S.T  # type: ignore[union-attr]

    @property
    def sd(self) -> np.ndarray:
        """Standard deviations sqrt(diag P)."""
        if self.S is not None and self.P is None:
            return np.sqrt(np.einsum("ij,ij->i", self.S, self.S))
        return np.sqrt(np.clip(np.diagonal(self.P), 0.0, None))  # type: ignore[arg-type]

    def with_(self, **changes: Any) -> "Belief":
        return replace(self, **changes)


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


@dataclass(frozen=True, init=False)
class UpdateResult:
    """What a filter update returns. ``belief`` is the input belief when ``accepted`` is False.
    (Fields written directly by the constructor, as for Belief: one is built per update.)"""

    belief: Belief
    innovation: np.ndarray
    S: np.ndarray
    nis: float
    accepted: bool

    def __init__(self, belief: Belief, innovation: np.ndarray, S: np.ndarray, nis: float, accepted: bool):
        self.__dict__.update(belief=belief, innovation=innovation, S=S, nis=nis, accepted=accepted)


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


# --------------------------------------------------------------------------- components
class Params(BaseModel):
    """Base of every plugin's Params model: unknown keys are errors, and every float (nested in lists,
    tuples and dicts too) must be finite: NaN or inf is an error naming the field. A field that means
    something by inf says so in its description and opts out with ``Field(..., allow_inf_nan=True)``."""

    model_config = ConfigDict(extra="forbid", arbitrary_types_allowed=True, allow_inf_nan=False)


@dataclass
class BuildContext:
    """What a component may need when it is built from a config.

    ``layout``: the process model's state layout (None while the process itself is built);
    ``beacons``: name -> position (m, NED or local frame of the config); ``sensor``: the sensor being
    wired (None for process/filter); ``base_dir``: folder of the config file, for relative paths;
    ``extra``: anything else a plugin wants to share (e.g. the system's gravity)."""

    layout: StateLayout | None = None
    beacons: Mapping[str, np.ndarray] = field(default_factory=dict)
    sensor: str | None = None
    base_dir: str = "."
    extra: dict[str, Any] = field(default_factory=dict)


class Component:
    """Base of every plugin component. Subclasses set ``name``, ``kind``, a pydantic ``Params`` model and a
    docstring (shown by ``fusion plugins --verbose``). Built as ``cls(params, context)``."""

    name: ClassVar[str] = ""
    kind: ClassVar[str] = ""
    Params: ClassVar[type[Params]] = Params

    def __init__(self, params: Params | None = None, context: BuildContext | None = None):
        self.params = params if params is not None else self.Params()
        self.context = context if context is not None else BuildContext()

    def __repr__(self) -> str:
        return f"<{self.kind} {self.name}>"


class ProcessModel(Component):
    """x_k = f(x_{k-1}, u, dt) + w, w ~ N(0, Q).

    ``layout`` is the state layout; ``input_dim`` the length of the control input u (0: no input);
    ``linear`` is True when f is affine in x (F independent of x), so a filter may predict as the linear KF.
    """

    kind: ClassVar[str] = "process"
    layout: StateLayout
    input_dim: int = 0
    linear: bool = False

    def f(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """Propagate states ``x`` (..., n) over ``dt`` seconds with input ``u`` (input_dim,) or None."""
        raise NotImplementedError

    def jacobian(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray | None:
        """dF/dx (n, n) at ``x`` (n,); None when the model has no analytic Jacobian."""
        return None

    def Q(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """Discrete process-noise covariance (n, n) over ``dt``."""
        raise NotImplementedError

    def normalize(self, x: np.ndarray) -> np.ndarray:
        """Bring states (..., n) back to their manifold (unit quaternions); identity by default."""
        return x

    # Optional methods, used when a model has them:
    # - ``align(x0, P0, u_mean) -> (x0, P0)`` refines the initial belief from the mean input over a static
    #   start (``initial.align_s`` in the config), e.g. roll and pitch from gravity for an INS.
    # - ``f_inputs(x, us, dts) -> x``: states (..., n) after the run of inputs ``us`` (k, input_dim), sample
    #   j held over ``dts[j]`` s; must equal k calls of ``f`` (to rounding). A fast path for the filters'
    #   ``predict_inputs`` (the scheduler passes the input samples between two measurements in one call).
    # - ``Q_inputs(x0, x1, us, dts) -> Q`` (n, n): process noise of such a run, from the mean before (x0)
    #   and after (x1); without it the filters sum ``Q`` over the samples.

    def input_from(self, message: Message) -> np.ndarray:
        """The control input u carried by an input-sensor message (default: its values as floats)."""
        u = message.floats()
        if u.shape != (self.input_dim,):
            raise MalformedMessage(f"process {self.name!r} expects {self.input_dim} input values, got {u.size}")
        return u


class MeasurementModel(Component):
    """z = h(x) + v, v ~ N(0, R). ``dim`` is m. ``observe`` turns a decoded message into an Observation
    (binding per-message context such as the beacon of a range); ``h`` is vectorised over leading axes."""

    kind: ClassVar[str] = "measurement"
    dim: int = 0
    #: Whether ``observe`` can take R from the message itself (a fix with its covariance): False means the
    #: sensor needs ``noise:`` in the config (``fusion validate`` checks it); None (default): not known.
    carries_R: bool | None = None

    def h(self, x: np.ndarray) -> np.ndarray:
        """Predicted measurement (..., m) for states x (..., n)."""
        raise NotImplementedError

    def jacobian(self, x: np.ndarray) -> np.ndarray | None:
        """dh/dx (m, n) at x (n,); None when there is no analytic Jacobian."""
        return None

    def residual(self, z: np.ndarray, z_hat: np.ndarray) -> np.ndarray:
        """z - z_hat, broadcast over leading axes (override to wrap angles)."""
        return z - z_hat

    # Optional: ``check(belief, sensor) -> list[Event]`` after each accepted update, e.g. a warning that the
    # geometry is degenerate at the current estimate (the range model's GDOP / mirror check). The scheduler
    # reports the events when a warning starts, and a ``cleared`` event when it stops.

    def observe(self, message: Message) -> Observation | None:
        """Observation for a decoded message (default: all values are z, this model predicts it)."""
        z = message.floats()
        if z.shape != (self.dim,):
            raise MalformedMessage(f"measurement {self.name!r} expects {self.dim} values, got {z.size}")
        return Observation(message.t, z, self)


class Gate(Component):
    """Validation gate on the normalised innovation squared (NIS = y^T S^-1 y)."""

    kind: ClassVar[str] = "gate"

    def accept(self, nis: float, dim: int) -> bool:
        raise NotImplementedError


class Filter(Component):
    """Shared interface of kf, ekf, iekf, ukf, srukf. Both methods return new objects, never mutate."""

    kind: ClassVar[str] = "filter"

    def initial_belief(self, t: float, x: np.ndarray, P: np.ndarray) -> Belief:
        """Belief in this filter's representation (P, or S for square-root filters)."""
        return Belief(t, np.asarray(x, float), P=np.asarray(P, float))

    def predict(self, belief: Belief, process: ProcessModel, u: np.ndarray | None, dt: float) -> Belief:
        raise NotImplementedError

    def update(self, belief: Belief, model: MeasurementModel, z: np.ndarray, R: np.ndarray,
               gate: Gate | None = None) -> UpdateResult:
        raise NotImplementedError

    # Optional: ``predict_inputs(belief, process, us (k, m), dts (k,)) -> Belief`` integrates a run of input
    # samples in order (sample j held over dts[j] s). The scheduler batches input samples into one call when
    # the filter has it; the built-ins do (sigma-point filters draw their points once per run).


class Decoder(Component):
    """Per-sensor decoding of a framed message (e.g. an NMEA sentence into NED position).
    Returns the decoded Message, or None when the message carries nothing to fuse; raises
    MalformedMessage for a bad one."""

    kind: ClassVar[str] = "decoder"

    def decode(self, message: Message) -> Message | None:
        return message


class Solver(Component):
    """Single-shot fixes (trilateration, TRIAD, ...). As a sensor preprocessor, ``feed`` gathers raw
    messages and returns the messages it produces (e.g. one position fix per cycle of ranges); events
    (e.g. ``no_fix`` with a reason) go to ``self.events``."""

    kind: ClassVar[str] = "solver"

    def feed(self, message: Message) -> list[Message]:
        raise NotImplementedError

    def flush(self) -> list[Message]:
        """Messages still gathered at the end of the input."""
        return []


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


class Source(Component):
    """Yields raw text lines of the log format (a recording, stdin, a serial port, a network stream).

    ``fusion run --input TEXT`` and ``fusion tui --input TEXT`` choose a source through the registry
    (fusion.sources.select): by URL scheme (``TEXT`` = ``scheme://...``, matched against ``schemes``),
    by a device path for sources with ``devices = True`` (a character device such as ``/dev/ttyUSB0``), by
    file suffix (``suffixes``), else the built-in ``recording``. ``live`` sources (a device, a socket)
    are never paced by the live view. ``open()``/``close()`` are optional: ``close`` may be called from
    another thread to end a blocked ``lines()``."""

    kind: ClassVar[str] = "source"
    schemes: ClassVar[tuple[str, ...]] = ()   # URL schemes read, e.g. ("udp",) for udp://host:port
    suffixes: ClassVar[tuple[str, ...]] = ()  # file suffixes read, lower case with the dot, e.g. (".log",)
    devices: ClassVar[bool] = False           # reads character devices (serial ports)
    live: ClassVar[bool] = False

    @classmethod
    def from_url(cls, url: str, **options: Any) -> "Source":
        """The source for the text given to ``--input``. Default: ``url`` goes to the first field of
        ``Params``, ``options`` (e.g. ``baud``) to the fields of the same names."""
        first = next(iter(cls.Params.model_fields))
        return cls(cls.Params(**{first: url, **options}))

    @property
    def label(self) -> str:
        """Where the lines come from, for summaries and the live view."""
        first = next(iter(type(self.params).model_fields), None)
        return str(getattr(self.params, first, self.name)) if first else self.name

    def lines(self):  # -> Iterator[str]
        raise NotImplementedError


class Sink(Component):
    """Consumes estimates and events (files, plots). ``fusion run --output PATH`` chooses a sink through
    the registry by the suffix of PATH (``suffixes``; fusion.sources.select.open_sink). A sink is closed
    once, at the end of the run."""

    kind: ClassVar[str] = "sink"
    suffixes: ClassVar[tuple[str, ...]] = ()  # file suffixes written, lower case with the dot, e.g. (".csv",)

    @classmethod
    def for_path(cls, path: str, layout: StateLayout) -> "Sink":
        """The sink writing to ``path`` for estimates of ``layout``. Default: ``Params(path=path)`` and a
        BuildContext with the layout."""
        return cls(cls.Params(path=path), BuildContext(layout=layout))

    def on_estimate(self, estimate: Estimate) -> None: ...

    def on_event(self, event: Event) -> None: ...

    def close(self) -> None: ...


class Simulator(Component):
    """Simulates one sensor from a truth trajectory (used by ``fusion simulate``)."""

    kind: ClassVar[str] = "simulator"


# --------------------------------------------------------------------------- importers (``fusion import``)
@dataclass(frozen=True)
class ImportRequest:
    """What ``fusion import`` asks an importer for: the time span ``start``..``end`` (s, on the output's time
    axis, i.e. from the log's own time zero; None: unbounded), the sensor names wanted (None: all the format
    has), the mapping file (CSV), and whether a truncated or corrupt file may be imported as far as it reads
    (``allow_partial``; otherwise it is an InputError). Importers read only what is asked for where the
    format allows it (topics, message types, columns) and cut the span themselves."""

    start: float | None = None
    end: float | None = None
    sensors: frozenset[str] | None = None
    mapping: str | None = None
    allow_partial: bool = False

    def wants(self, sensor: str) -> bool:
        """True when ``sensor`` (``imu2``), or its family (``imu``: every instance), was asked for."""
        if self.sensors is None:
            return True
        return sensor in self.sensors or sensor.rstrip("0123456789") in self.sensors

    def wants_family(self, family: str) -> bool:
        """True when any sensor of ``family`` (``imu``, ``imu2``, ...) was asked for: its data must be read."""
        if self.sensors is None:
            return True
        return any(s.rstrip("0123456789") == family for s in self.sensors)


@dataclass
class Stream:
    """One sensor's samples: times ``t`` (k,) in s and ``values`` (k, m), columns named by ``fields``
    (written as ``# fields SENSOR ...``). ``formats``: a format spec a column (``".7f"``), default
    ``".9g"`` (round-trips float32); a column of ``dtype=object`` holds labels (beacon names). ``meta``:
    ``# SENSOR key: value`` header lines (units, source topic). ``repeat``: the fields form a group that
    repeats on a line (``beacon range ...``); ``rows`` then holds ready value tuples instead of ``values``."""

    sensor: str
    fields: tuple[str, ...]
    t: np.ndarray
    values: np.ndarray | None = None
    formats: tuple[str, ...] | None = None
    meta: dict[str, str] = field(default_factory=dict)
    repeat: bool = False
    rows: list[tuple[Any, ...]] | None = None

    def __len__(self) -> int:
        return int(len(self.t))


@dataclass
class ImportedLog:
    """What an importer returns: header metadata (``# key: value``, in order), the streams, notes for the
    user (printed by the command, e.g. "gps: 3 samples without a fix dropped"), every file it read besides
    the one it was given (``inputs``: never overwritten by the output), and the log's own text messages
    (``messages``: "Takeoff detected" at t; written as ``# message T: text`` header comments)."""

    meta: dict[str, str] = field(default_factory=dict)
    streams: list[Stream] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    inputs: list[str] = field(default_factory=list)
    messages: list[tuple[float, str]] = field(default_factory=list)  # the log's text messages (t s, text)


class Importer(Component):
    """Reads a log of another format (PX4 ULog, ArduPilot DataFlash, CSV by a mapping) into streams that
    ``fusion import`` writes in the fusion log format. ``suffixes``: the file name endings it reads
    (``(".ulg",)``), used to choose it; ``sensors``: the sensor families it can produce (``imu``, ``gps``,
    ``mag``, ``baro``, ``reference``, ...). Units out are SI and frames NED/FRD (DESIGN.md), except GPS
    latitude/longitude in degrees and altitude in metres above mean sea level, and magnetic field in uT."""

    kind: ClassVar[str] = "importer"
    suffixes: ClassVar[tuple[str, ...]] = ()
    sensors: ClassVar[tuple[str, ...]] = ()

    def read(self, path: str, request: ImportRequest) -> ImportedLog:
        """Read ``path``; raise InputError (what and where) for a file that is not of this format or is
        damaged, ConfigError for a bad mapping or request."""
        raise NotImplementedError


# --------------------------------------------------------------------------- optional capabilities
# Detected once when the scheduler is built (isinstance on these runtime-checkable protocols), never in a
# hot path.
@runtime_checkable
class AlignsState(Protocol):
    """A measurement model that initialises part of the state from its observations over the static start
    (``initial.align_s``), e.g. the attitude by TRIAD from the mean magnetometer sample and the mean
    specific force. The scheduler gathers the sensor's observations until the filter starts (instead of
    rejecting them) and calls this after the process model's own ``align``."""

    def align_state(self, x0: np.ndarray, P0: np.ndarray, u_mean: np.ndarray,
                    observations: Sequence[Observation], R: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """(x0, P0) refined; ``u_mean`` the mean input over the static start, ``R`` the sensor's noise."""
        ...


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
