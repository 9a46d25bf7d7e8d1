"""The system YAML: pydantic schema, and wiring into plugin instances (``load_system``).

A component is selected by registry name, either as a bare name (``filter: ukf``) or as a mapping with
``type`` plus the plugin's own parameters (``filter: {type: ukf, alpha: 0.5}``), validated by the
plugin's ``Params`` model. Example::

    name: uwb_example
    recording: ../recordings/example_2d.log      # relative to this file
    beacons: {B1: [0, 0], B2: [20, 0], B3: [20, 20], B4: [0, 20]}
    process: {type: pv, dims: 2, spectral_density: 0.5}
    initial: {mean: {p: [1, 1], v: [0, 0]}, sd: {p: 2.0, v: 1.0}}
    filter: ukf
    sensors:
      uwb: {model: range, noise: {sd: 0.1}, gate: {type: chi2, probability: 0.999}}
    scheduler: {max_latency: 0.2, late_policy: drop}
    output: {on_update: true, rate_hz: null}
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal, Union
import warnings

import numpy as np
from pydantic import (BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, ValidationInfo,
                      field_validator, model_validator)

from fusion.api import (Aligns, BuildContext, CapabilityWarning, Component, ConfigError, Decoder, Filter, Gate,
                        KeepsGateState, MeasurementModel, ProcessModel, Solver, has, near_misses)
from fusion.api.components import reject_bool_numbers
from fusion.health.spec import HealthSpec
from fusion.recovery import RecoverySpec
from fusion.registry import Registry, default_registry
from fusion.yamlsource import LocatedYAML, load_yaml, pydantic_errors


SENSOR_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_.\-]*$")   # as fusion.logformat parses a line's sensor
RESERVED_SENSORS = ("truth", "reference")
BEACON_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_.:\-/]*$")   # a label of fusion.logformat
#: Largest beacon coordinate (m): far beyond any local or Earth-centred frame (6.4e6 m), and small enough
#: that ranges and their squares stay finite in every solver.
MAX_BEACON_M = 1e8


def _not_bool(v: Any) -> Any:
    """A YAML true/false where a coordinate belongs (pydantic would take it as 1.0 / 0.0)."""
    if isinstance(v, bool):
        raise ValueError(f"a coordinate must be a number, got {str(v).lower()}")
    return v


Coordinate = Annotated[float, BeforeValidator(_not_bool)]


class _Strict(BaseModel):
    """Unknown keys are errors; every float (nested ones too) must be finite, NaN and inf are errors; a
    YAML true/false is no number."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _no_bool_numbers(cls, value: Any, info: ValidationInfo) -> Any:
        return reject_bool_numbers(cls, value, info.field_name)


#: Largest initial standard deviation (in the block's SI unit: m, m/s, rad, ...). The first update leaves a
#: posterior variance of about the measurement's, computed as P0 - K S K^T; it keeps no digit once P0 / R
#: passes 1 / eps = 4.5e15 (float64). 1e6 against a 1 cm sensor is that ratio (1e16); measured on
#: configs/uwb_pv_ukf.yaml (0.1 m ranges), the EKF still converges at sd 1e7 and diverges at 1e8 (1046
#: non-positive-definite repairs). No physical prior is wider: 1e6 m is a continent, 1e6 m/s is 30x orbital
#: speed.
from fusion.config_values import MAX_INITIAL_SD  # noqa: E402 (= 1e6, used by the wiring's checks there too)
#: Fastest fixed-rate output (Hz): each output costs a prediction and a row (~200 B of CSV); beyond the
#: fastest sensor (an IMU at 100 Hz-1 kHz) more rows carry no information (1 kHz over an hour: 3.6 M rows).
MAX_OUTPUT_RATE_HZ = 1000.0
#: The longest reorder window, s: a minute (the default max_predict_s) is longer than any link's jitter; a
#: longer known delay is a sensor's time_offset. The buffer's memory is bounded apart (fusion.run.reorder).
MAX_LATENCY_S = 60.0
#: Largest |time_offset| (s): Unix time is 1.7e9 s, so an offset between time bases fits; 1e10 s (317
#: years) is no clock's.
MAX_TIME_OFFSET_S = 1e10


ComponentSpec = Union[str, dict[str, Any]]

#: Longest path (bytes) and path component the system takes (Linux PATH_MAX and NAME_MAX).
PATH_MAX, NAME_MAX = 4096, 255


def check_path_text(v: str) -> str:
    """A file name from a config as text: no NUL byte, no component over NAME_MAX bytes and no more than
    PATH_MAX bytes in all (the system refuses them when the file is opened, as an internal error)."""
    if "\0" in v:
        raise ValueError(f"a path cannot hold a NUL byte (at character {v.index(chr(0))} of {v[:60]!r}...)")
    size = len(os.fsencode(v))
    if size > PATH_MAX:
        raise ValueError(f"a path of {size} bytes, longer than the system's {PATH_MAX} ({v[:60]!r}...)")
    longest = max(v.split("/"), key=lambda part: len(os.fsencode(part)))
    if len(os.fsencode(longest)) > NAME_MAX:
        raise ValueError(f"a path component of {len(os.fsencode(longest))} bytes, longer than the system's "
                         f"{NAME_MAX} ({longest[:60]!r}...)")
    return v


class NoiseSpec(_Strict):
    """Measurement noise: ``sd`` (scalar or one per component, in the measurement's units) or a full ``R``."""

    sd: float | list[float] | None = None
    R: list[list[float]] | None = None

    @model_validator(mode="after")
    def _one_of(self) -> "NoiseSpec":
        if self.sd is not None and self.R is not None:
            raise ValueError("give sd or R, not both (sd: standard deviations, R: the full covariance)")
        return self


class SensorSpec(_Strict):
    role: Literal["input", "measurement"] = "measurement"
    decoder: ComponentSpec = "line"
    preprocessor: ComponentSpec | None = None
    model: ComponentSpec | None = None
    noise: NoiseSpec | float | list[float] | None = None
    gate: ComponentSpec | None = None
    time_offset: float = Field(0.0, ge=-MAX_TIME_OFFSET_S, le=MAX_TIME_OFFSET_S, description="s added to the "
                               "sensor's time stamps: a clock's offset, or minus a known latency (a sensor "
                               "that stamps its measurements 0.2 s late takes -0.2)")
    max_gap: float | None = Field(None, gt=0.0, description="input sensors: report a gap between samples "
                                  "longer than this (s)")
    recovery: RecoverySpec | None = Field(None, description="recover from a lock-out (fusion.recovery); off by default")
    min_coverage: float = Field(0.5, ge=0.0, le=1.0, description="input sensors: warn when the recording's "
                                "header says its samples integrate less of the time (fusion.imu_coverage)")
    max_rotation_deg: float = Field(5.0, gt=0.0, description="input sensors: warn when the header says it turns "
                                    "more between two samples (deg, fusion.imu_coverage)")
    enabled: bool = True


class InitialSpec(_Strict):
    """Initial belief by block name: ``mean`` values and ``sd`` (scalar or per element), or full ``P``.
    ``from_sensor`` takes the position block from that sensor's fixes before the start: the latest, or all of
    an ``align_s`` window the process model judged static, combined (fusion.run.startup)."""

    mean: dict[str, float | list[float]] = Field(default_factory=dict)
    sd: dict[str, float | list[float]] = Field(default_factory=dict)
    P: list[list[float]] | None = None
    from_sensor: str | None = None
    align_s: float = Field(0.0, ge=0.0, description="static start (s) over which the process model aligns "
                           "itself from the mean input (e.g. roll/pitch from gravity); 0: no alignment")

    @model_validator(mode="after")
    def _sd_or_P(self):
        if self.P is not None and self.sd:
            raise ValueError("give sd or P, not both (P is the whole initial covariance: its diagonal is "
                             "the variances)")
        return self


class SchedulerSpec(_Strict):
    max_latency: float = Field(0.0, ge=0.0, le=MAX_LATENCY_S, allow_inf_nan=False,
                               description="reorder buffer length, s (at most MAX_LATENCY_S: a longer delay is a "
                                           "sensor's time_offset, not a transport latency)")
    late_policy: Literal["drop", "replay"] = "drop"
    history: int = Field(500, ge=1, le=100_000, description="beliefs kept for replay")
    future_s: float = Field(5.0, gt=0.0, allow_inf_nan=False,
                            description="s a stamp may be ahead of (or behind) the newest accepted time before it "
                                        "is held as a wild stamp or a clock jump (fusion.run.clock)")
    resync_after: int = Field(3, ge=1, description="messages of a sensor that must agree on a new time base "
                                                   "before its clock is re-synchronised")
    max_predict_s: float = Field(60.0, gt=0.0, allow_inf_nan=False,
                                 description="longest prediction over a gap, s; a longer gap is bounded to it")
    cadence_k: float = Field(2.0, ge=0.0, le=1000.0, allow_inf_nan=False,
                             description="a stamp past the stream's newest time (+ max_latency) by more than "
                                         "cadence_floor_s and ahead of its sensor's newest stamp, or of the stream's "
                                         "newest time, by more than cadence_k x their learned message spacing + "
                                         "cadence_floor_s is held until its sensor's next message (fusion.run.clock); "
                                         "0: off; off with late_policy replay, which expects arrival jitter")
    cadence_floor_s: float = Field(0.02, gt=0.0, allow_inf_nan=False,
                                   description="s a stamp may always be past the stream's newest time (+ max_latency) "
                                               "and past its sensor's cadence (clock jitter; the whole bound before a "
                                               "spacing is learned); less than future_s")

    @model_validator(mode="after")
    def _floor_inside_future(self) -> "SchedulerSpec":
        if self.cadence_floor_s >= self.future_s:
            raise ValueError(f"cadence_floor_s ({self.cadence_floor_s:g} s) must be less than future_s "
                             f"({self.future_s:g} s): a stamp farther than future_s is held anyway")
        return self


class OutputSpec(_Strict):
    on_update: bool = True
    rate_hz: float | None = Field(None, gt=0.0, le=MAX_OUTPUT_RATE_HZ, description="fixed-rate outputs by "
                                  "prediction, Hz (at most MAX_OUTPUT_RATE_HZ)")

    @model_validator(mode="after")
    def _some_output(self):
        if not self.on_update and self.rate_hz is None:
            raise ValueError("on_update: false and no rate_hz: the run would emit no estimate (give rate_hz, "
                             "or on_update: true)")
        return self


class EvaluationSpec(_Strict):
    """How ``fusion run`` scores estimates against truth."""

    settle_s: float = Field(0.0, ge=0.0, description="skip the first seconds in the statistics")
    position: list[str] | None = Field(None, description="elements of the position error, e.g. [px, py] "
                                       "for a horizontal accuracy (default: the whole block p)")


class SmootherSpec(_Strict):
    """``smoother:`` in a system YAML: Rauch-Tung-Striebel smoothing after the forward filter, as
    ``fusion run --smooth`` (``lag_s``: the fixed-lag smoother, as ``--smooth-lag``); fusion/smoothing/."""

    enabled: bool = Field(True, description="smooth every `fusion run` of this config")
    lag_s: float | None = Field(None, ge=0.0, description="fixed lag (s); none: the full smoother")
    disk: bool | None = Field(None, description="the forward records on disk: true, false, or none (on "
                                                "disk past an in-memory budget)")


class SystemSpec(_Strict):
    name: str
    description: str = ""
    recording: str | None = None
    beacons: dict[str, list[Coordinate]] = Field(default_factory=dict)
    process: ComponentSpec
    initial: InitialSpec = Field(default_factory=InitialSpec)
    filter: ComponentSpec = "ekf"
    sensors: dict[str, SensorSpec]
    scheduler: SchedulerSpec = Field(default_factory=SchedulerSpec)
    output: OutputSpec = Field(default_factory=OutputSpec)
    evaluation: EvaluationSpec = Field(default_factory=EvaluationSpec)
    smoother: SmootherSpec | None = None
    health: HealthSpec = Field(default_factory=HealthSpec)
    prefer: Literal["config"] | dict[Literal["magnetic_field", "beacons", "receivers", "gravity", "origin"],
                                     Literal["config"]] = Field(
        default_factory=dict, description="where the config and the recording's header disagree on a value "
        "(fusion.header_checks), use the config's instead of refusing the run: `config` for all, or per quantity")

    @field_validator("recording")
    @classmethod
    def _recording_path(cls, v: str | None) -> str | None:
        return v if v is None else check_path_text(v)

    @field_validator("beacons")
    @classmethod
    def _beacon_dims(cls, v: dict[str, list[float]]) -> dict[str, list[float]]:
        first = None
        for name, pos in v.items():
            if len(pos) not in (2, 3):
                raise ValueError(f"beacon {name!r} needs 2 or 3 coordinates, got {len(pos)}")
            if not BEACON_NAME.match(name) or name.lower() in ("nan", "inf", "infinity"):
                raise ValueError(f"beacon {name!r} can never be named by a log line (a label: an ASCII letter or _, "
                                 "then letters, digits, _ . : - /)")
            if any(abs(c) > MAX_BEACON_M for c in pos):
                raise ValueError(f"beacon {name!r}: a coordinate beyond {MAX_BEACON_M:g} m ({pos})")
            if first is None:
                first = (name, len(pos))
            elif len(pos) != first[1]:
                raise ValueError(f"beacon {name!r} has {len(pos)} coordinates and {first[0]!r} {first[1]}: give "
                                 "every beacon 2 (x y) or every beacon 3 (x y z)")
        return v


@dataclass
class SensorRuntime:
    """One configured sensor, wired: its components and counters."""

    name: str
    role: str
    decoder: Decoder
    preprocessor: Solver | None
    model: MeasurementModel | None
    R: np.ndarray | None
    gate: Gate | None
    time_offset: float
    max_gap: float | None = None
    recovery: RecoverySpec | None = None
    counters: dict[str, int] = field(default_factory=lambda: dict(received=0, used=0, rejected=0, malformed=0, late=0,
                                                                             absorbed=0))


@dataclass
class System:
    """A wired system: everything the scheduler needs."""

    spec: SystemSpec
    path: Path | None
    process: ProcessModel
    filter: Filter
    sensors: dict[str, SensorRuntime]
    x0: np.ndarray
    P0: np.ndarray
    beacons: dict[str, np.ndarray]
    registry: Registry
    world: Any = None     # fusion.world.RecordingWorld the components were wired with, or None

    @property
    def layout(self):
        return self.process.layout

    @property
    def recording(self) -> Path | None:
        if self.spec.recording is None:
            return None
        base = self.path.parent if self.path else Path(".")
        try:
            return (base / self.spec.recording).resolve()
        except (RuntimeError, OSError):  # a symlink loop: opening it names the loop (ELOOP)
            return Path(os.path.abspath(base / self.spec.recording))


def _split(spec: ComponentSpec, doc: LocatedYAML | None, loc: list[Any]) -> tuple[str, dict[str, Any]]:
    if isinstance(spec, str):
        return spec, {}
    params = dict(spec)
    name = params.pop("type", None)
    if not isinstance(name, str):
        where = doc.where(loc) if doc else ".".join(map(str, loc))
        raise ConfigError(f"{where}: a component needs 'type: NAME' (got keys {sorted(spec)})")
    return name, params


_CHECKED: set[type] = set()


def _report_near_misses(cls: type) -> None:
    """Warn, once per class, about a method one edit away from a capability (a misspelt ``f_inputs``
    silently switches the feature off): fusion.api.capabilities.near_misses."""
    if cls in _CHECKED:
        return
    _CHECKED.add(cls)
    for miss in near_misses(cls):
        warnings.warn(miss, CapabilityWarning, stacklevel=3)


def build_component(registry: Registry, kind: str, spec: ComponentSpec, ctx: BuildContext,
                    doc: LocatedYAML | None = None, loc: list[Any] | None = None) -> Component:
    """Instantiate a component of ``kind`` from its spec, validating params with its Params model."""
    loc = loc or []
    name, params = _split(spec, doc, loc)
    where = doc.where(loc) if doc else ".".join(map(str, loc))
    cls = registry.get(kind, name, where)
    _report_near_misses(cls)
    try:
        p = cls.Params(**params)
    except ValidationError as exc:
        if doc is not None:
            raise pydantic_errors(doc, exc, loc) from None
        raise ConfigError(f"{where}: {pydantic_errors(None, exc, data=params)}") from None
    except Exception as exc:  # a plugin's own validator raising another exception (pydantic passes it through)
        raise _build_failed(registry, cls, kind, name, where, "failed to validate its parameters", exc) from exc
    try:
        return cls(p, ctx)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    except ValueError as exc:
        raise ConfigError(f"{where}: {kind} {name!r}: {exc}") from None
    except Exception as exc:  # a plugin's calibration file that is missing, a RuntimeError of its own, ...
        raise _build_failed(registry, cls, kind, name, where, "failed to build", exc) from exc


def _probe_gate_state(registry: Registry, gate: Gate, where: str) -> None:
    """A gate that keeps state (fusion.api.KeepsGateState) gives its run's first state at wiring too, so that
    an ``initial_state()`` that raises is one config error naming the gate, its package and the config line
    (exit 2, also from ``fusion validate``), not an exception out of the run; each run still asks afresh."""
    if not has(gate, KeepsGateState):
        return
    try:
        gate.initial_state()  # type: ignore[attr-defined]
    except Exception as exc:
        raise _build_failed(registry, type(gate), "gate", gate.name, where, "failed in initial_state()", exc) from exc


def _build_failed(registry: Registry, cls: type, kind: str, name: str, where: str, what: str,
                  exc: Exception) -> Exception:
    """The error for a component that raised while it was built: a ConfigError naming the config line, the
    component, its kind and package and the exception (``--debug`` shows its traceback, chained), for a
    third-party component, and for any that fails to open a file (an OSError: a path the user gave);
    otherwise (a built-in's bug) ``exc`` itself, an internal error."""
    provider = registry.provider_of(cls)
    if provider.endswith("(built-in)") and not isinstance(exc, OSError):
        return exc
    return ConfigError(f"{where}: component {name!r} ({kind}, from {provider}) {what}: {type(exc).__name__}: {exc}")


from fusion.config_values import initial_belief_values, noise_matrix  # noqa: E402 (the numbers of a config, split out)
from fusion_plugins.filters.checks import checked  # noqa: E402 (a plugin's models are checked at their calls)


def wire(spec: SystemSpec, doc: LocatedYAML | None = None, path: Path | None = None,
         registry: Registry | None = None, filter_override: ComponentSpec | None = None,
         world: Any = None) -> System:
    """Build every component of a validated SystemSpec and check dimensions. ``world``: what the recording
    to be replayed declares (fusion.world.RecordingWorld), given to every component as
    ``context.extra["world"]``; None: the world of the spec's own ``recording:`` when it is a file."""
    reg = registry or default_registry()
    base_dir = str(path.parent) if path else "."
    if world is None and spec.recording:
        from fusion.world import read_world

        world = read_world(Path(base_dir) / spec.recording)
    beacons = {k: np.asarray(v, float) for k, v in spec.beacons.items()}
    extra: dict[str, Any] = {"world": world} if world is not None else {}
    if world is not None and not world.streamed:      # what the config leaves out, the recording declares
        if not beacons:
            beacons = {k: np.asarray(d.value, float) for k, d in world.beacons.items() if len(d.value) in (2, 3)}
        if world.gravity is not None:
            extra["gravity"] = world.gravity.value
    ctx = BuildContext(layout=None, beacons=beacons, base_dir=base_dir, extra=dict(extra))
    process = checked(build_component(reg, "process", spec.process, ctx, doc, ["process"]))
    assert isinstance(process, ProcessModel)
    layout = process.layout
    fctx = BuildContext(layout, beacons, None, base_dir, dict(extra))
    if filter_override is not None:  # from the command line: no file line to name
        filt = build_component(reg, "filter", filter_override, fctx, None, ["filter (--filter/--filter-param)"])
    else:
        filt = build_component(reg, "filter", spec.filter, fctx, doc, ["filter"])
    sensors: dict[str, SensorRuntime] = {}
    for sname, s in spec.sensors.items():
        loc = ["sensors", sname]
        where = doc.where(loc) if doc else f"sensors.{sname}"
        if not SENSOR_NAME.match(sname):
            raise ConfigError(f"{where}: {sname!r} can never name a log line's sensor (an ASCII letter or _, then ASCII letters, "
                              "digits, _ . -)")
        if sname in RESERVED_SENSORS:
            raise ConfigError(f"{where}: {sname!r} lines are never fed to the filter (the log format reserves "
                              f"{', '.join(RESERVED_SENSORS)}); name the sensor otherwise")
        if not s.enabled:
            continue
        sctx = BuildContext(layout, beacons, sname, base_dir, dict(extra))
        decoder = build_component(reg, "decoder", s.decoder, sctx, doc, [*loc, "decoder"])
        pre = build_component(reg, "solver", s.preprocessor, sctx, doc, [*loc, "preprocessor"]) if s.preprocessor else None
        model = gate = R = None
        if s.role == "measurement":
            if s.model is None:
                raise ConfigError(f"{where}: a measurement sensor needs 'model: NAME'")
            model = checked(build_component(reg, "measurement", s.model, sctx, doc, [*loc, "model"]))
            R = noise_matrix(s.noise, model.dim, doc.where([*loc, "noise"]) if doc else f"{where}.noise")
            if R is None and model.carries_R is False:
                raise ConfigError(f"{where}: a measurement sensor needs 'noise:' (sd or R): its model "
                                  f"{model.name!r} takes no covariance from its messages")
            gate = build_component(reg, "gate", s.gate, sctx, doc, [*loc, "gate"]) if s.gate else None
            if gate is not None:
                _probe_gate_state(reg, gate, doc.where([*loc, "gate"]) if doc else f"{where}.gate")
        elif process.input_dim == 0:
            raise ConfigError(f"{where}.role: 'input' but process {process.name!r} takes no control input")
        if s.recovery is not None:
            if s.role != "measurement":
                raise ConfigError(f"{where}.recovery: only a measurement sensor can recover the filter")
            for i, b in enumerate([*s.recovery.blocks, *s.recovery.also_inflate]):
                if b not in layout:
                    bad = doc.where([*loc, "recovery", "blocks", i]) if doc else f"{where}.recovery.blocks"
                    raise ConfigError(f"{bad}: state has no block {b!r}; blocks are {[x.name for x in layout.blocks]}")
            size = sum(layout[b].stop - layout[b].start for b in s.recovery.blocks)
            if s.recovery.action == "reset" and model is not None and model.dim < size and pre is None:
                raise ConfigError(f"{where}.recovery: action 'reset' sets {s.recovery.blocks} from the measurement, "
                                  f"but {model.name!r} measures {model.dim} value(s) for {size} state elements; "
                                  "use action: inflate")
        sensors[sname] = SensorRuntime(sname, s.role, decoder, pre, model, R, gate, s.time_offset, s.max_gap,
                                       s.recovery)
    check_offsets_fit_latency(spec, doc)
    if getattr(filt, "linear_only", False):
        _check_linear(filt, process, sensors, doc.where(["filter"]) if doc and filter_override is None
                      else "filter (--filter)" if filter_override is not None else "filter")
    inputs = [n for n, s in sensors.items() if s.role == "input"]
    if len(inputs) > 1:
        raise ConfigError(f"{path or 'config'}: sensors: at most one input sensor, got {inputs}")
    if process.input_dim and not inputs:
        raise ConfigError(f"{path or 'config'}: sensors: process {process.name!r} needs an input sensor (role: input)")
    if spec.initial.from_sensor and spec.initial.from_sensor not in sensors:
        raise ConfigError(f"{doc.where(['initial', 'from_sensor']) if doc else 'initial.from_sensor'}: no sensor {spec.initial.from_sensor!r}")
    if spec.initial.from_sensor and sensors[spec.initial.from_sensor].role != "measurement":
        raise ConfigError(f"{doc.where(['initial', 'from_sensor']) if doc else 'initial.from_sensor'}: sensor "
                          f"{spec.initial.from_sensor!r} is an input; the initial position comes from a measurement "
                          f"sensor ({', '.join(n for n, r in sensors.items() if r.role == 'measurement') or 'none'})")
    if spec.initial.align_s and not has(process, Aligns):
        raise ConfigError(f"{doc.where(['initial', 'align_s']) if doc else 'initial.align_s'}: process {process.name!r} cannot align itself")
    for i, name in enumerate(spec.evaluation.position or []):
        if name not in layout.names:
            raise ConfigError(f"{doc.where(['evaluation', 'position', i]) if doc else 'evaluation.position'}: "
                              f"state has no element {name!r}; elements are {list(layout.names)}")
    x0, P0 = initial_belief_values(spec, process, doc)
    if spec.initial.from_sensor:
        from fusion.initial_checks import check_from_sensor

        check_from_sensor(spec.initial.from_sensor, sensors[spec.initial.from_sensor], layout, x0,
                          doc.where(["initial", "from_sensor"]) if doc else "initial.from_sensor")
    return System(spec, path, process, filt, sensors, x0, P0, beacons, reg, world)  # type: ignore[arg-type]


def check_offsets_fit_latency(spec: SystemSpec, doc: LocatedYAML | None = None) -> None:
    """Each enabled sensor's ``time_offset`` fits in the reorder buffer: a sensor whose offset lies more than
    ``scheduler.max_latency`` (s) below another's lands that far behind the stream's newest time, so under
    either late policy its messages arrive behind the released horizon (every one dropped as late, or each
    a replay). Only the spread between sensors matters: one shared offset moves the whole stream. Raises a
    ConfigError naming the sensor's ``time_offset`` line, the other sensor and both figures."""
    offsets = {n: s.time_offset for n, s in spec.sensors.items() if s.enabled}
    latency = spec.scheduler.max_latency
    for name, off in offsets.items():
        others = {n: o for n, o in offsets.items() if n != name}
        if not others:
            return
        ahead = max(others, key=others.__getitem__)
        behind = others[ahead] - off
        if behind > latency:
            loc = ["sensors", name, "time_offset"]
            where = doc.where(loc) if doc else ".".join(loc)
            raise ConfigError(f"{where}: {off:g} s puts {name}'s messages {behind:g} s behind {ahead}'s "
                              f"(time_offset {others[ahead]:g} s), more than scheduler.max_latency "
                              f"({latency:g} s): every one would arrive behind the released horizon and be "
                              f"dropped as late. Give scheduler.max_latency >= {behind:g}")


def _check_linear(filt, process: ProcessModel, sensors: dict[str, SensorRuntime], where: str) -> None:
    """The rule for a ``linear_only`` filter (kf): the process and every measurement model must declare
    ``linear = True`` (f and h affine in x); the first that does not is a ConfigError."""
    others = "use ekf, iekf, ukf or srukf"
    if not process.linear:
        raise ConfigError(f"{where}: filter {filt.name!r} needs a linear process model; process {process.name!r} "
                          f"is not linear (linear = False): {others}")
    for sname, sr in sensors.items():
        if sr.model is not None and not sr.model.linear:
            raise ConfigError(f"{where}: filter {filt.name!r} needs linear measurement models; sensor {sname!r} "
                              f"uses {sr.model.name!r}, which is not linear (linear = False): {others}")


#: load_system's default ``recording``: the config's own
OWN_RECORDING: Any = object()


def load_system(path: str | Path, registry: Registry | None = None,
                filter_override: ComponentSpec | None = None, recording: Any = OWN_RECORDING) -> System:
    """Load, validate and wire a system YAML. Raises ConfigError naming file, line and field.
    ``recording``: the input the system will replay, whose header declares its world (fusion.world): a
    path, None (a stream: no header known ahead), or OWN_RECORDING (the config's own ``recording:``)."""
    from fusion.world import read_world

    doc = load_yaml(path)
    try:
        spec = SystemSpec.model_validate(doc.data)
    except ValidationError as exc:
        raise pydantic_errors(doc, exc) from None
    if recording is OWN_RECORDING:
        recording = (Path(path).parent / spec.recording) if spec.recording else None
    world = read_world(recording) if recording is not None else None
    if world is None:     # a stream: no header known ahead (not the config's own recording's)
        from fusion.world import RecordingWorld

        world = RecordingWorld(str(recording) if recording is not None else "-", streamed=True)
    return wire(spec, doc, Path(path), registry, filter_override, world)
