"""Translation of a robot_localization parameter file (``ekf.yaml``, ROS 1 or ROS 2 layout) into a system YAML
of the ``omni`` process and the ``pose`` / ``twist`` / ``imu`` models (``fusion import-config``, docs/ros.md).

Frames: robot_localization works in REP-103 ENU / FLU, the project in NED / FRD (fusion.importers.rosbag_frames),
so the world x and y swap (in every ``*_config`` and matrix), z, pitch and the body y/z axes change sign, and
yaw becomes pi/2 - yaw: vectors and matrices are mapped by ``J = blockdiag(T_ne, diag(1,-1,-1), D, D, D)``.

Sensors are named as ``fusion import`` names their topics (``/wheel/odometry`` -> ``wheel_odometry``), or as a
recording (``--recording``) names them: its header says each sensor's topic, ROS frame and the static tf, which
with ``--tf`` give the IMU and twist mounts. robot_localization's GPS path (navsat_transform_node's
``/odometry/gps`` fused as an ``odomN``) is translated to the recording's NavSatFix sensor with the ``position``
model, when the recording has one. Every parameter that has no counterpart is listed, with why.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fusion.errors import ConfigError

from .rosbag_frames import D_FLU, J_RPY, T_NE, body_quat, quat_matrix
from .rosbag_map import sensor_name

STATE_J = np.zeros((15, 15))
for _k, _M in enumerate((T_NE, J_RPY, D_FLU, D_FLU, D_FLU)):
    STATE_J[3 * _k:3 * _k + 3, 3 * _k:3 * _k + 3] = _M
PERMUTE = (1, 0, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14)   # an ENU/FLU axis flag -> the NED/FRD one
KINDS = {"odom": "pose", "pose": "pose", "twist": "twist", "imu": "imu"}
#: The state axes each kind of robot_localization sensor can fuse (its message has them)
FUSES = {"odom": range(12), "pose": range(6), "twist": range(6, 12), "imu": (3, 4, 5, 9, 10, 11, 12, 13, 14)}
TWO_D = (2, 3, 4, 8, 9, 10, 14)
IGNORED = {   # parameter -> why it has no counterpart here
    "frequency": "the output rate: output.rate_hz is set from it",
    "sensor_timeout": "no fixed-rate filter loop: predictions run to each message",
    "publish_tf": "no ROS graph", "publish_acceleration": "no ROS graph", "print_diagnostics": "no ROS graph",
    "map_frame": "frames are NED/FRD here, docs/ros.md", "odom_frame": "frames are NED/FRD here",
    "base_link_frame": "the body frame (mounts are given on it with --tf)", "world_frame": "frames are NED/FRD here",
    "transform_time_offset": "no tf output", "transform_timeout": "static transforms only (--tf, /tf_static)",
    "debug": "fusion run --summary-json and the event lines", "debug_out_file": "see debug",
    "permit_corrected_publication": "no publication", "reset_on_time_jump": "the run's clock guard handles jumps",
    "predict_to_current_time": "no publication", "disabled_at_startup": "no services",
    "dynamic_process_noise_covariance": "use_dynamic_process_noise is not modelled",
    "use_sim_time": "the bag's header stamps are the clock here",
}
UNSUPPORTED = {
    "use_dynamic_process_noise": "velocity-scaled process noise is not modelled: the static matrix is used",
    "use_control": "control input (cmd_vel) is not modelled", "control_config": "see use_control",
    "control_timeout": "see use_control", "stamped_control": "see use_control",
    "acceleration_limits": "see use_control", "deceleration_limits": "see use_control",
    "acceleration_gains": "see use_control", "deceleration_gains": "see use_control",
    "smooth_lagged_data": "late messages: scheduler.late_policy replay (set by hand)",
    "history_length": "see smooth_lagged_data (scheduler.history)",
}
PER_SENSOR_IGNORED = ("queue_size", "nodelay", "pose_use_child_frame")


@dataclass
class Translation:
    """The system YAML (as data) and what could not be translated (one line each)."""

    config: dict[str, Any]
    untranslated: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Tf:
    """``--tf PARENT CHILD X Y Z ROLL PITCH YAW`` (m, rad; ROS FLU frames)."""

    parent: str
    child: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]

    def mount(self) -> tuple[list[float], list[float]]:
        """(lever arm m body FRD, rotation [w x y z] sensor FRD -> body FRD)."""
        from scipy.spatial.transform import Rotation

        x, y, z, w = Rotation.from_euler("ZYX", self.rpy[::-1]).as_quat()
        q = body_quat(np.array([w, x, y, z]))
        return [float(v) for v in D_FLU @ np.asarray(self.xyz)], [round(float(v), 12) for v in q]


def parameters(doc: Any, where: str) -> tuple[dict[str, Any], str]:
    """The robot_localization parameters of a loaded YAML and the layout found: ROS 2 (``node: ros__parameters:``),
    ROS 1 under a node name, or flat."""
    if not isinstance(doc, dict):
        raise ConfigError(f"{where}: not a robot_localization parameter file (a YAML mapping)")
    if _is_params(doc):
        return doc, "ROS 1 (flat)"
    for node, body in doc.items():
        if isinstance(body, dict) and isinstance(body.get("ros__parameters"), dict):
            return body["ros__parameters"], f"ROS 2 (node {node})"
        if isinstance(body, dict) and _is_params(body):
            return body, f"ROS 1 (node {node})"
    raise ConfigError(f"{where}: no robot_localization parameters found (odom0, imu0, process_noise_covariance, ... "
                      "at the top, under a node name, or under NODE: ros__parameters:)")


def _is_params(d: dict) -> bool:
    return any(re.fullmatch(r"(odom|pose|twist|imu)\d+", str(k)) for k in d) or "process_noise_covariance" in d


def _matrix(values: Any, key: str) -> np.ndarray:
    a = np.asarray(values, float)
    if a.size == 225:
        return a.reshape(15, 15)
    if a.size == 15:
        return np.diag(a)
    raise ConfigError(f"{key}: expected 225 values (15 x 15) or 15, got {a.size}")


def _select(flags: Any, key: str) -> list[bool]:
    if not isinstance(flags, list) or len(flags) != 15 or not all(isinstance(b, bool) for b in flags):
        raise ConfigError(f"{key}: expected 15 booleans (x y z roll pitch yaw vx vy vz vroll vpitch vyaw ax ay az)")
    return [bool(flags[PERMUTE[i]]) for i in range(15)]


def state_mean(enu: Any) -> list[float]:
    """robot_localization's initial_state (ENU/FLU) in the omni state's NED/FRD."""
    x = np.asarray(enu, float)
    if x.size != 15:
        raise ConfigError(f"initial_state: expected 15 values, got {x.size}")
    out = STATE_J @ x
    out[5] = math.pi / 2 - x[5]
    return [float(v) for v in out]


@dataclass
class RecordingInfo:
    """What a recording's header says of its ROS sensors: topic, frame, message type, mount."""

    path: str
    topics: dict[str, str] = field(default_factory=dict)       # sensor -> topic
    types: dict[str, str] = field(default_factory=dict)        # sensor -> message type
    frames: dict[str, str] = field(default_factory=dict)       # sensor -> ROS frame_id
    mounts: dict[str, tuple[list[float], list[float]]] = field(default_factory=dict)
    tfs: list[Tf] = field(default_factory=list)

    @classmethod
    def read(cls, path: str) -> "RecordingInfo":
        """From a recording's header, or from a bag (``.bag``, ``.db3``, ``.mcap``, a ROS 2 bag folder) read by
        the rosbag importer as ``fusion import`` would."""
        from pathlib import Path

        p = Path(path)
        if p.suffix in (".bag", ".db3", ".mcap") or p.is_dir():
            from fusion.api import ImportRequest

            from .rosbag import RosbagImporter
            from .writer import render

            log = RosbagImporter().read(path, ImportRequest())
            log.streams = [s for s in log.streams if len(s)]
            return cls._parse(path, render(log))
        with open(path, encoding="utf-8", errors="replace") as fh:
            return cls._parse(path, fh)

    @classmethod
    def _parse(cls, path: str, lines) -> "RecordingInfo":
        info = cls(path)
        for line in lines:
            if not line.startswith("#"):
                break
            m = re.match(r"# (\S+) (topic|frame_id|mount): (.*)", line.rstrip("\n"))
            if m:
                sensor, key, text = m.groups()
                if key == "topic":
                    topic, _, typ = text.partition(" (")
                    info.topics[sensor], info.types[sensor] = topic, typ.rstrip(")")
                elif key == "frame_id":
                    info.frames[sensor] = text
                else:
                    w = text.split()
                    info.mounts[sensor] = ([float(v) for v in w[1:4]], [float(v) for v in w[8:12]])
                continue
            m = re.match(r"# tf (\S+) (\S+): (.*)", line)
            if m:
                v = [float(x) for x in m.group(3).split()[:6]]
                info.tfs.append(Tf(m.group(1), m.group(2), tuple(v[:3]), tuple(v[3:6])))  # type: ignore[arg-type]
        if not info.topics:
            raise ConfigError(f"--recording {path}: no ROS topics in its header (a recording `fusion import` made "
                              "of a bag says '# SENSOR topic: ...')")
        return info

    def sensor_of(self, topic: str) -> str | None:
        return next((s for s, t in self.topics.items() if t.strip("/") == topic.strip("/")), None)

    def navsat(self) -> str | None:
        return next((s for s, t in self.types.items() if t.endswith("NavSatFix")), None)


def translate(params: dict[str, Any], layout: str, recording: RecordingInfo | None = None, tfs: list[Tf] = (),
              filter_name: str | None = None, name: str = "robot_localization") -> Translation:
    """The system YAML (data) of robot_localization ``params`` (see the module)."""
    out = Translation({})
    used: set[str] = set()
    two_d = bool(params.get("two_d_mode", False))
    used.add("two_d_mode")
    pnc = _matrix(params["process_noise_covariance"], "process_noise_covariance") if "process_noise_covariance" in params \
        else None
    used.add("process_noise_covariance")
    process: dict[str, Any] = {"type": "omni", "two_d_mode": two_d}
    if pnc is not None:
        q = STATE_J @ pnc @ STATE_J.T
        process["process_noise_covariance"] = [float(v) for v in np.diag(q)] if np.count_nonzero(q - np.diag(np.diag(q))) == 0 \
            else [[float(v) for v in row] for row in q]
    else:
        out.untranslated.append("process_noise_covariance: not given; robot_localization's default diagonal is used")
    cfg = out.config
    cfg["name"] = name
    cfg["description"] = f"translated by fusion import-config from a robot_localization parameter file ({layout})"
    if recording is not None:
        cfg["recording"] = recording.path
    cfg["process"] = process
    cfg["initial"] = _initial(params, used, out)
    cfg["filter"] = _filter(params, used, filter_name)
    cfg["sensors"] = _sensors(params, used, out, two_d, recording, list(tfs))
    rate = float(params.get("frequency", 30.0))
    used.add("frequency")
    cfg["output"] = {"on_update": False, "rate_hz": rate}
    cfg["scheduler"] = {"max_latency": 0.0, "late_policy": "drop"}
    for key in params:
        if key in used:
            continue
        if key in UNSUPPORTED:
            out.untranslated.append(f"{key}: {UNSUPPORTED[key]}")
        elif key in IGNORED:
            if key != "frequency":
                out.untranslated.append(f"{key}: ignored ({IGNORED[key]})")
        else:
            out.untranslated.append(f"{key}: unknown to this translation, ignored")
    return out


def _initial(params: dict, used: set, out: Translation) -> dict[str, Any]:
    used.update(("initial_state", "initial_estimate_covariance"))
    x = state_mean(params.get("initial_state", [0.0] * 15))
    P = _matrix(params["initial_estimate_covariance"], "initial_estimate_covariance") \
        if "initial_estimate_covariance" in params else None
    if P is None:
        out.untranslated.append("initial_estimate_covariance: not given; robot_localization's default 1e-9 on the "
                                "diagonal is used (the filter starts certain of its initial state)")
        P = np.eye(15) * 1e-9
    P = STATE_J @ P @ STATE_J.T
    blocks = {"p": x[0:3], "roll": x[3], "pitch": x[4], "yaw": x[5], "vb": x[6:9], "w": x[9:12], "ab": x[12:15]}
    return {"mean": blocks, "P": [[float(v) for v in row] for row in P]}


def _filter(params: dict, used: set, name: str | None) -> dict[str, Any]:
    ukf = {k: params[k] for k in ("alpha", "kappa", "beta") if k in params}
    used.update(ukf)
    kind = name or ("ukf" if ukf else "ekf")
    spec: dict[str, Any] = {"type": kind}
    if kind == "ukf":
        spec.update({"alpha": float(ukf.get("alpha", 0.001)), "kappa": float(ukf.get("kappa", 0.0)),
                     "beta": float(ukf.get("beta", 2.0))})
    return spec


def _sensors(params: dict, used: set, out: Translation, two_d: bool, rec: RecordingInfo | None,
             tfs: list[Tf]) -> dict[str, Any]:
    sensors: dict[str, Any] = {}
    base = str(params.get("base_link_frame", "base_link"))
    for key in sorted(k for k in params if re.fullmatch(r"(odom|pose|twist|imu)\d+", str(k))):
        family = re.match(r"[a-z]+", key).group(0)  # type: ignore[union-attr]
        topic = str(params[key])
        own = {k for k in params if k.startswith(key + "_")}
        used.update(own | {key})
        if f"{key}_config" not in params:
            out.untranslated.append(f"{key}: no {key}_config; robot_localization then fuses nothing of it: left out")
            continue
        select = _select(params[f"{key}_config"], f"{key}_config")
        sensor = rec.sensor_of(topic) if rec is not None else None
        gps = rec is not None and sensor is None and rec.navsat() is not None and family == "odom" and "gps" in topic
        if gps:
            sensor = rec.navsat()
            out.untranslated.append(f"{key}: {topic} is navsat_transform_node's output, which is not in the recording: "
                                    f"the recording's NavSatFix sensor {sensor!r} is fused instead with the position "
                                    "model (NED about the recording's first fix; the world frame's x taken as east)")
            sensors[sensor] = {"model": {"type": "position", "dim": 2 if two_d else 3}}
            continue
        if sensor is None:
            sensor = sensor_name(topic)
            if rec is not None:
                out.untranslated.append(f"{key}: topic {topic} is not in {rec.path}; the sensor is named {sensor!r}")
        fused = [i for i in FUSES[family] if select[i] and not (two_d and i in TWO_D)]
        if not fused:
            article = "an" if family[0] in "aeiou" else "a"
            out.untranslated.append(f"{key}_config: selects nothing {article} {family} message has"
                                    f"{' outside two_d_mode' if two_d else ''}: the sensor is left out")
            continue
        model: dict[str, Any] = {"type": KINDS[family], "select": _names([i in fused for i in range(15)])}
        if two_d:
            model["two_d_mode"] = True
        for opt in ("differential", "relative"):
            if params.get(f"{key}_{opt}") and family in ("odom", "pose", "imu"):
                model[opt] = True
        if family == "imu":
            if params.get(f"{key}_remove_gravitational_acceleration"):
                model["remove_gravitational_acceleration"] = True
                if "gravitational_acceleration" in params:
                    model["gravity"] = float(params["gravitational_acceleration"])
                    used.add("gravitational_acceleration")
        if family in ("imu", "twist"):
            _mount(model, sensor, rec, tfs, base, out, key)
        spec: dict[str, Any] = {"model": model}
        gate = _gate(params, key, out)
        if gate is not None:
            spec["gate"] = gate
        sensors[sensor] = spec
        for opt in PER_SENSOR_IGNORED:
            if f"{key}_{opt}" in params:
                out.untranslated.append(f"{key}_{opt}: ignored (no ROS subscriber here)")
    return sensors


def _names(select: list[bool]) -> list[str]:
    names = ("x", "y", "z", "roll", "pitch", "yaw", "vx", "vy", "vz", "vroll", "vpitch", "vyaw", "ax", "ay", "az")
    return [n for n, b in zip(names, select) if b]


def _mount(model: dict, sensor: str, rec: RecordingInfo | None, tfs: list[Tf], base: str, out: Translation,
           key: str) -> None:
    frame = rec.frames.get(sensor) if rec is not None else None
    given = next((t for t in tfs if frame is not None and t.child == frame and t.parent == base), None)
    if given is not None:
        arm, q = given.mount()
    elif rec is not None and sensor in rec.mounts:
        arm, q = rec.mounts[sensor]
    else:
        if frame not in (None, base):
            out.untranslated.append(f"{key}: frame {frame!r} has no static transform to {base!r} (give one with --tf "
                                    f"{base} {frame} X Y Z ROLL PITCH YAW): mounted as the body")
        return
    if any(abs(v) > 0 for v in arm) and model["type"] == "twist":
        model["lever_arm"] = arm
    if abs(q[0] - 1.0) > 1e-12:
        model["mount_rotation"] = q


def _gate(params: dict, key: str, out: Translation) -> dict[str, Any] | None:
    found = {k: float(v) for k, v in params.items() if k.startswith(key + "_") and k.endswith("_rejection_threshold")}
    if not found:
        return None
    d = min(found.values())
    if len(set(found.values())) > 1:
        out.untranslated.append(f"{key}: one gate per sensor here: the smallest of {sorted(found)} ({d:g}) is used")
    if d >= 1e3:
        return None   # robot_localization's "no rejection" (its default is the largest double)
    return {"type": "chi2", "n_sigma": d}
