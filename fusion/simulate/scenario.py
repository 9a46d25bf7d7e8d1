"""The scenario file of ``fusion simulate``: pydantic models (``extra="forbid"``) and the loader.

A scenario names a trajectory, beacons (name -> position), an optional geodetic origin (for GPS) and the
sensors, each selected by registry name (``type: imu``) with the simulator's own ``Params``. Errors name
the file, its YAML line and the field path, as a system config's do (fusion.yamlsource, the one locator
and formatter of both): ``scenarios/x.yaml:12: sensors.uwb.noise_sd: ...``.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Any, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from fusion.api import ConfigError
from fusion.yamlsource import LocatedYAML, pydantic_errors

_LABEL = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
_SENSOR = re.compile(r"^[A-Za-z_][A-Za-z0-9_.\-]*$")


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)   # every float finite, nested ones too


Vec = list[float]


class Waypoint(_Model):
    """A waypoint: ``[x, y]`` / ``[x, y, z]`` (m, NED) or a mapping with options."""

    at: Vec = Field(description="position (m): [x, y] or [x, y, z] (z down)")
    stop: float = Field(0.0, ge=0, description="seconds standing still at this waypoint")
    speed: float | None = Field(None, gt=0, description="cruise speed (m/s) of the run that starts here "
                                                         "(the start or after a stop)")
    radius: float | None = Field(None, ge=0, description="turning radius (m) of the corner here")
    turn_speed: float | None = Field(None, gt=0, description="speed (m/s) through the corner here: the "
                                                             "vehicle slows down before the turn")

    @model_validator(mode="before")
    @classmethod
    def _from_list(cls, v: Any) -> Any:
        if isinstance(v, (list, tuple)):
            return {"at": list(v)}
        return v

    @field_validator("at")
    @classmethod
    def _dims(cls, v: Vec) -> Vec:
        if len(v) not in (2, 3):
            raise ValueError(f"a waypoint has 2 or 3 coordinates, got {len(v)}")
        return v


class WaypointsTrajectory(_Model):
    """A ground vehicle or pedestrian along smoothly rounded waypoint legs, heading along the path, pitch
    along the slope, no roll; stops and a static start/end; longitudinal acceleration by quintic ramps."""

    type: Literal["waypoints"]
    waypoints: list[Waypoint] = Field(min_length=2)
    speed: float = Field(1.0, gt=0, description="cruise speed (m/s)")
    max_accel: float = Field(0.5, gt=0, description="peak longitudinal acceleration (m/s^2)")
    radius: float = Field(1.0, ge=0, description="default turning radius at corners (m)")
    static_start: float = Field(0.0, ge=0, description="seconds at rest before moving")
    static_end: float = Field(0.0, ge=0, description="seconds at rest after the last waypoint")


class RandomWalkTrajectory(_Model):
    """A robot whose position and attitude random-walk by a step each ``step_interval`` seconds (paper 003:
    5 mm and 0.57 deg per firing), smoothed by a quintic spline through the steps, kept inside ``bounds``."""

    type: Literal["random_walk"]
    start: Vec = Field(description="initial position (m, NED)")
    start_attitude_deg: Vec = Field([0.0, 0.0, 0.0], description="initial roll, pitch, yaw (deg)")
    step_interval: float = Field(0.1, gt=0, description="seconds between steps")
    position_step_sd: float = Field(0.005, ge=0, description="position step sd per axis (m)")
    angle_step_sd_deg: float = Field(0.57, ge=0, description="roll/pitch/yaw step sd (deg)")
    bounds: list[Vec] | None = Field(None, description="[[xmin, xmax], [ymin, ymax], [zmin, zmax]] (m)")
    max_tilt_deg: float = Field(30.0, gt=0, description="roll and pitch are reflected at this bound (deg)")
    static_start: float = Field(0.0, ge=0, description="seconds at rest before moving")
    seed: int = Field(0, description="seed of the walk itself (the sensor noise follows the scenario seed)")

    @field_validator("start", "start_attitude_deg")
    @classmethod
    def _three(cls, v: Vec) -> Vec:
        if len(v) != 3:
            raise ValueError(f"expected 3 values, got {len(v)}")
        return v


class WhiteAccelerationTrajectory(_Model):
    """The constant-velocity (white-acceleration) model's own motion: per axis, position and velocity driven
    by white acceleration of power spectral density ``spectral_density`` (q, m^2/s^3), the ``pv`` process's
    model, drawn exactly on a grid of ``step`` s (Q = q [[h^3/3, h^2/2], [h^2/2, h]]). A matched truth for a
    filter that states this model (a control for experiments). ``bounds`` keep it in an area: ``redraw`` draws
    the whole walk again until it stays inside (the model conditioned on staying in), ``reflect`` folds it
    at the walls (an elastic bounce: the velocity's normal component flips, an impulse the model lacks)."""

    type: Literal["white_acceleration"]
    start: Vec = Field(description="mean initial position (m): [x, y] in a 2-D scenario, [x, y, z] in 3-D")
    start_velocity: Vec | None = Field(None, description="mean initial velocity (m/s); None: at rest")
    start_sd: float = Field(0.0, ge=0, description="sd per axis of the drawn initial position (m)")
    start_velocity_sd: float = Field(0.0, ge=0, description="sd per axis of the drawn initial velocity (m/s)")
    spectral_density: float = Field(gt=0, description="PSD of the white acceleration per axis (m^2/s^3)")
    duration: float = Field(gt=0, description="seconds of the walk (the scenario's duration, if given, is at "
                                              "most this)")
    step: float = Field(0.01, gt=0, description="grid of the exact discretisation (s); between grid points "
                                                "the motion is the cubic through the two states")
    bounds: list[Vec] | None = Field(None, description="[[xmin, xmax], [ymin, ymax](, [zmin, zmax])] (m), "
                                                       "checked at the grid points")
    boundary: Literal["redraw", "reflect"] = Field("redraw", description="how bounds are kept: redraw the "
                                                   "walk until it stays inside, or reflect it at the walls")
    max_draws: int = Field(1000, ge=1, le=100000, description="redraw: draws before giving up (an error)")
    seed: int = Field(0, ge=0, description="seed of the walk itself (the sensor noise follows the scenario seed)")


Trajectory = Annotated[Union[WaypointsTrajectory, RandomWalkTrajectory, WhiteAccelerationTrajectory],
                       Field(discriminator="type")]


class Origin(_Model):
    """Geodetic origin of the local NED frame (WGS84)."""

    lat_deg: float = Field(ge=-90, le=90)
    lon_deg: float = Field(ge=-180, le=180)
    alt_m: float = 0.0


class TruthSpec(_Model):
    rate_hz: float | None = Field(None, gt=0, description="truth rate (Hz); default: the highest sensor rate")
    precision: int = Field(6, ge=1, le=12, description="decimals of the truth values")


class Scenario(_Model):
    """A whole scenario file."""

    name: str | None = Field(None, description="scenario name (default: the file name without .yaml)")
    description: str = ""
    seed: int = Field(0, ge=0, description="seed of all the noise (overridden by --seed)")
    duration: float | None = Field(None, gt=0, description="seconds (default: the trajectory's own length)")
    dim: Literal[2, 3] = Field(3, description="2: planar (truth px py vx vy, ranges in the plane); 3: full")
    gravity: float = Field(9.80665, gt=0, description="g (m/s^2); g_n = [0, 0, g] in NED")
    precision: int = Field(6, ge=1, le=12, description="decimals of sensor values (a sensor may override)")
    beacons: dict[str, Vec] = Field(default_factory=dict, description="name -> position (m)")
    origin: Origin | None = None
    start_utc: str = Field("2024-01-01T12:00:00", description="UTC time of t = 0 (GPS sentences)")
    trajectory: Trajectory
    truth: TruthSpec = Field(default_factory=TruthSpec)
    sensors: dict[str, dict[str, Any]] = Field(min_length=1)

    @field_validator("beacons")
    @classmethod
    def _beacons(cls, v: dict[str, Vec]) -> dict[str, Vec]:
        for name, pos in v.items():
            if not _LABEL.match(name):
                raise ValueError(f"beacon name {name!r} must start with a letter (letters, digits, _)")
            if len(pos) not in (2, 3):
                raise ValueError(f"beacon {name}: expected [x, y] or [x, y, z], got {len(pos)} values")
        return v

    @field_validator("sensors")
    @classmethod
    def _sensors(cls, v: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
        for name, spec in v.items():
            if not _SENSOR.match(name) or name == "truth":
                raise ValueError(f"bad sensor name {name!r} (letters, digits, _ . -; not 'truth')")
            if not isinstance(spec, dict) or "type" not in spec:
                raise ValueError(f"sensor {name!r} needs a 'type' (a simulator name, see `fusion plugins`)")
        return v


# --------------------------------------------------------------------------- loading and errors
def load_scenario(path: str | Path) -> tuple[Scenario, str]:
    """Read and validate a scenario file; returns (scenario, its YAML text). Raises ConfigError."""
    from fusion.yamlsource import read_yaml_text

    p = Path(path)
    text = read_yaml_text(p, "scenario file")  # a regular file, bounded: never /dev/zero into memory
    return parse_scenario(text, str(p)), text


def parse_scenario(text: str, where: str = "<scenario>") -> Scenario:
    """Validate scenario YAML text (the name defaults to the file stem)."""
    doc = LocatedYAML.from_text(text, where)   # duplicate keys, nesting and alias bombs: errors with the line
    if not isinstance(doc.data, dict):
        raise ConfigError(f"{where}: a scenario is a YAML mapping (name, trajectory, sensors, ...)")
    try:
        sc = Scenario.model_validate(doc.data)
    except ValidationError as exc:
        raise pydantic_errors(doc, exc) from None
    if sc.name is None:
        sc = sc.model_copy(update={"name": Path(where).stem})
    return sc
