"""The component bases every plugin derives from (process and measurement models, filters, gates,
decoders, solvers, sources, sinks, simulators) and the ``Params`` base of their YAML parameters."""
from __future__ import annotations

from dataclasses import dataclass, field
import types
from typing import Annotated, Any, ClassVar, Generic, Literal, Mapping, TypeVar, Union, get_args, get_origin

import numpy as np
from pydantic import BaseModel, ConfigDict, ValidationInfo, field_validator

from fusion.errors import MalformedMessage

from .capabilities import KeepsGateState, has
from .gates import GateDecision, GateRun
from .messages import Estimate, Event, Message, Observation, UpdateResult
from .state import Belief, StateLayout

__all__ = ["Params", "BuildContext", "Component", "ProcessModel", "MeasurementModel", "Gate", "Filter",
           "Decoder", "Solver", "Source", "Sink", "Simulator"]


def _nonfinite(value: Any, path: str, allow_inf: bool) -> str | None:
    """The path and value of the first non-finite float in ``value`` (nested in lists, tuples, sets, dict
    values, numpy arrays), or None; with ``allow_inf``, only a NaN counts."""
    if isinstance(value, (float, np.floating)):
        v = float(value)
        if v != v or (not allow_inf and v - v != 0.0):
            return f"{path}: {v}"
        return None
    if isinstance(value, BaseModel):   # validated by its own model
        return None
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "fc":
            bad = np.isnan(value) if allow_inf else ~np.isfinite(value)
            if bad.any():
                at = tuple(int(i) for i in np.argwhere(bad)[0])
                return f"{path}.{'.'.join(map(str, at))}: {value[at]}"
        return None
    if isinstance(value, dict):
        items = value.items()
    elif isinstance(value, (list, tuple, set, frozenset)):
        items = enumerate(value)
    else:
        return None
    for k, v in items:
        found = _nonfinite(v, f"{path}.{k}", allow_inf)
        if found:
            return found
    return None


def _leaf_types(ann: Any) -> set:
    """The element types an annotation admits (``object`` where it admits anything, a Literal, a mapping)."""
    origin = get_origin(ann)
    if origin is Annotated:
        return _leaf_types(get_args(ann)[0])
    if origin is None:
        return {ann}
    if origin in (list, tuple, set, frozenset, Union, types.UnionType):
        out: set = set()
        for a in get_args(ann):
            out |= _leaf_types(a)
        return out
    return {object}


def _numbers_only(ann: Any) -> bool:
    leaves = _leaf_types(ann) - {type(None), Ellipsis}
    return bool(leaves) and leaves <= {int, float}


def reject_bool_numbers(model: type[BaseModel], value: Any, field_name: str | None) -> Any:
    """A YAML ``true``/``false`` (alone or in a list) where the field takes only numbers is an error; pydantic
    would read it as 1 or 0 (``sd: true`` a noise of 1). Used by ``Params`` and the config's own models."""
    if isinstance(value, bool) or (isinstance(value, (list, tuple)) and any(isinstance(v, bool) for v in value)):
        f = model.model_fields.get(field_name) if field_name else None
        if f is not None and _numbers_only(f.annotation):
            raise ValueError(f"a number is needed, got {str(value).lower()} (YAML true/false)")
    return value


class Params(BaseModel):
    """Base of every plugin's Params model: unknown keys are errors, and every float (nested in lists,
    tuples and dicts too, typed or not: ``dict``, ``list``, ``Any``, numpy arrays) must be finite: NaN or inf
    is an error naming the field. A field that means something by inf says so in its description and opts
    in with ``Field(..., allow_inf_nan=True)``: inf is then accepted, NaN still is not."""

    model_config = ConfigDict(extra="forbid", arbitrary_types_allowed=True, allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _no_bool_numbers(cls, value: Any, info: ValidationInfo) -> Any:
        return reject_bool_numbers(cls, value, info.field_name)

    @field_validator("*", mode="after")
    @classmethod
    def _finite(cls, value: Any, info: ValidationInfo) -> Any:
        # pydantic checks typed floats (allow_inf_nan=False); this covers what it does not: floats inside an
        # untyped dict/list/Any, and NaN in a field that allows inf
        if value is None or isinstance(value, (int, str)):
            return value
        f = cls.model_fields.get(info.field_name) if info.field_name else None
        allow_inf = f is not None and any(getattr(m, "allow_inf_nan", None) is True for m in f.metadata)
        found = _nonfinite(value, info.field_name or "value", allow_inf)
        if found:
            rule = ("NaN is never a parameter (this field allows inf)" if allow_inf
                    else "NaN and inf are not parameters (a field that means something by inf opts in with "
                         "allow_inf_nan=True)")
            raise ValueError(f"{found}: {rule}")
        return value


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


_ParamsBase = Params
#: The type of a component's ``params`` (its own ``Params`` model).
P = TypeVar("P", bound=Params)


class Component(Generic[P]):
    """Base of every plugin component. Subclasses set ``name``, ``kind``, a pydantic ``Params`` model and a
    docstring (shown by ``fusion plugins --verbose``). Built as ``cls(params, context)``.

    Generic over its Params model, so ``self.params.x`` is typed: ``class Baro(MeasurementModel[BaroParams])``
    with ``Params = BaroParams``. Optional behaviour is declared by implementing a capability protocol
    (fusion.api.capabilities), detected once at wiring."""

    name: ClassVar[str] = ""
    kind: ClassVar[str] = ""
    Params: ClassVar[type[_ParamsBase]] = _ParamsBase
    #: The names of the log values it reads, in their order (``("beacon", "range")``), or None (any). A
    #: recording whose ``# fields SENSOR ...`` line names the same values in another order is refused at
    #: that line (read by position, the columns would be swapped silently); other names get a warning.
    fields: ClassVar[tuple[str, ...] | None] = None
    params: P

    def __init__(self, params: P | None = None, context: BuildContext | None = None):
        self.params = params if params is not None else self.Params()  # type: ignore[assignment]
        self.context = context if context is not None else BuildContext()

    def __repr__(self) -> str:
        return f"<{self.kind} {self.name}>"


class ProcessModel(Component[P]):
    """x_k = f(x_{k-1}, u, dt) + w, w ~ N(0, Q).

    ``layout`` is the state layout; ``input_dim`` the length of the control input u (0: no input);
    ``linear`` is True when f is affine in x (F independent of x), so a filter may predict as the linear KF.
    """

    kind: ClassVar[str] = "process"
    layout: StateLayout
    input_dim: int = 0
    #: The input message's values by name, in order (``("ax", "ay", "az", "gx", "gy", "gz")``), or None:
    #: as ``Component.fields``, for the sensor whose role is ``input``.
    input_fields: ClassVar[tuple[str, ...] | None] = None
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
        """Bring states (..., n) back to their manifold: the layout's unit quaternion blocks
        (``StateLayout.normalize``; x itself when there are none)."""
        return self.layout.normalize(x)

    # Optional capabilities (fusion.api.capabilities): Aligns (``align``), IntegratesInputRuns
    # (``f_inputs``), InputRunNoise (``Q_inputs``), NonAdditiveProcessNoise (``f_with_noise``).

    def input_from(self, message: Message) -> np.ndarray:
        """The control input u carried by an input-sensor message (default: its values as floats)."""
        u = message.floats()
        if u.shape != (self.input_dim,):
            raise MalformedMessage(f"process {self.name!r} expects {self.input_dim} input values, got {u.size}")
        return u


class MeasurementModel(Component[P]):
    """z = h(x) + v, v ~ N(0, R). ``dim`` is m. ``observe`` turns a decoded message into an Observation
    (binding per-message context such as the beacon of a range); ``h`` is vectorised over leading axes."""

    kind: ClassVar[str] = "measurement"
    dim: int = 0
    #: Whether ``observe`` can take R from the message itself (a fix with its covariance). False (the
    #: default) means the sensor needs ``noise:`` in the config: ``fusion validate`` refuses it without.
    carries_R: bool = False
    #: True when h is affine in x (H independent of x): the linear ``kf`` accepts only such models.
    linear: bool = False

    def h(self, x: np.ndarray) -> np.ndarray:
        """Predicted measurement (..., m) for states x (..., n)."""
        raise NotImplementedError

    def jacobian(self, x: np.ndarray) -> np.ndarray | None:
        """dh/dx (m, n) at x (n,); None when there is no analytic Jacobian."""
        return None

    def residual(self, z: np.ndarray, z_hat: np.ndarray) -> np.ndarray:
        """z - z_hat, broadcast over leading axes (override to wrap angles)."""
        return z - z_hat

    # Optional capabilities (fusion.api.capabilities): ChecksGeometry (``check``), PositionFromFix
    # (``position_from``), NonAdditiveMeasurementNoise (``h_with_noise``), AlignsState, UsesInput,
    # PseudoMeasurement, ReportsInfo.

    def observe(self, message: Message) -> Observation | None:
        """Observation for a decoded message (default: all values are z, this model predicts it)."""
        z = message.floats()
        if z.shape != (self.dim,):
            raise MalformedMessage(f"measurement {self.name!r} expects {self.dim} values, got {z.size}")
        return Observation(message.t, z, self)


class Gate(Component[P]):
    """Validation gate on the normalised innovation squared (NIS = y^T S^-1 y), an immutable object.

    ``check`` returns the decision as a value (fusion.api.GateDecision: accepted, the threshold, reasons);
    the gate counts nothing and keeps nothing. A gate with memory declares KeepsGateState
    (``initial_state()``) and gets its state passed in and returns the next one; the run keeps it
    (fusion.api.GateRun, what the filters are given). Optional: HasThreshold (``threshold(dim)``)."""

    kind: ClassVar[str] = "gate"

    def check(self, nis: float, dim: int, state: Any = None) -> tuple[GateDecision, Any]:
        """(decision, next state) for a measurement of ``dim`` values with NIS ``nis`` (dimensionless; NaN
        must be refused); ``state`` is None for a gate without KeepsGateState, and returned as None."""
        raise NotImplementedError

    def accept(self, nis: float, dim: int) -> bool:
        """The decision alone, for a gate without memory (a filter may be given the gate itself). A gate
        with KeepsGateState must be wrapped in a GateRun, which keeps its state: TypeError here."""
        if has(self, KeepsGateState):
            raise TypeError(f"gate {self.name!r} keeps per-run state: give the filter GateRun(gate) "
                            "(fusion.api), which holds it")
        return self.check(nis, dim, None)[0].accepted


class Filter(Component[P]):
    """Shared interface of kf, ekf, iekf, ukf, srukf. Both methods return new objects, never mutate."""

    kind: ClassVar[str] = "filter"
    #: True for a filter that is exact only for affine models (``kf``): wiring refuses a process or
    #: measurement model that does not declare ``linear = True`` (exit 2 naming the filter's line).
    linear_only: ClassVar[bool] = False

    def initial_belief(self, t: float, x: np.ndarray, P: np.ndarray) -> Belief:
        """Belief in this filter's representation (P, or S for square-root filters)."""
        return Belief(t, np.asarray(x, float), P=np.asarray(P, float))

    def predict(self, belief: Belief, process: ProcessModel, u: np.ndarray | None, dt: float) -> Belief:
        raise NotImplementedError

    def update(self, belief: Belief, model: MeasurementModel, z: np.ndarray, R: np.ndarray,
               gate: Gate | GateRun | None = None) -> UpdateResult:
        """The belief after measurement ``z`` (m,) with noise ``R`` (m, m), or the input belief when
        ``gate.accept(nis, m)`` refuses it (the only call a filter makes on its gate; the run passes a
        GateRun)."""
        raise NotImplementedError

    # Optional capability: PredictsInputRuns (``predict_inputs``, fusion.api.capabilities); the built-ins
    # have it (the sigma-point filters draw their points once per run).


class Decoder(Component[P]):
    """Per-sensor decoding of a framed message (e.g. an NMEA sentence into NED position).
    Returns the decoded Message, or None when the message carries nothing to fuse; raises
    MalformedMessage for a bad one."""

    kind: ClassVar[str] = "decoder"

    def decode(self, message: Message) -> Message | None:
        return message


class Solver(Component[P]):
    """Single-shot fixes (trilateration, TRIAD, ...). As a sensor preprocessor, ``feed`` gathers raw
    messages and returns what it produces (e.g. one position fix per cycle of ranges); events (e.g.
    ``no_fix`` with a reason) are appended to ``self.events``, which the run takes (:meth:`take_events`)
    after every ``feed`` and ``flush`` and reports in its event stream."""

    kind: ClassVar[str] = "solver"

    def __init__(self, params: P | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        self.events: list[Event] = []

    def take_events(self) -> list[Event]:
        """The events since the last call (and forget them)."""
        events = self.events
        if not events:
            return []
        self.events = []
        return events

    def feed(self, message: Message) -> list[Message]:
        raise NotImplementedError

    def flush(self) -> list[Message]:
        """Messages still gathered at the end of the input."""
        return []


class Source(Component[P]):
    """Yields raw text lines of the log format (a recording, stdin, a serial port, a network stream).

    ``fusion run --input TEXT`` and ``fusion tui --input TEXT`` choose a source through the registry
    (fusion.sources.select): by URL scheme (``TEXT`` = ``scheme://...``, matched against ``schemes``),
    by a device path for sources with ``devices = True`` (a character device such as ``/dev/ttyUSB0``), by
    file suffix (``suffixes``), else the built-in ``recording``. ``live`` sources (a device, a socket)
    are never paced by the live view. Optional capabilities (fusion.api.capabilities): Opens (``open``),
    Closes (``close``, which may be called from another thread to end a blocked ``lines()``), ReportsIdle
    (``on_idle``), ReportsStatus (``on_status``)."""

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

    def input_paths(self) -> tuple[str, ...]:
        """The local files this source reads (default: none), as paths. ``fusion run`` and ``fusion tui``
        refuse an output (``--output``, ``--summary-json``, ``--plot``, ``--record``) that is one of them,
        also through a link, ``--force`` or not: an output never replaces an input. A source that reads a
        file (a recording, a capture a plugin replays, however its URL names it: ``file://PATH``,
        ``pcap:///PATH``) returns its path; one that reads a port, a socket or standard input returns ().
        Called before the source is opened."""
        return ()

    def lines(self):  # -> Iterator[str]
        raise NotImplementedError


class Sink(Component[P]):
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


class Simulator(Component[P]):
    """Simulates one sensor from a truth trajectory (used by ``fusion simulate``)."""

    kind: ClassVar[str] = "simulator"
