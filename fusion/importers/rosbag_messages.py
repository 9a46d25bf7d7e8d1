"""The ROS message types ``fusion import`` maps by type, each to one row of log fields (NED / FRD, SI).

Covariances travel with the message as the upper triangle of the matrix, row by row (``c00 c01 .. c22`` for
3 x 3, ``c00 .. c55`` for 6 x 6), in the converted frame (fusion.importers.rosbag_frames), so a model can
use them as R as robot_localization does. ROS marks "not provided" with -1 in the first element (sensor_msgs
Imu); that -1 is kept (a diagonal element keeps its value under the frame change).

=====================================================  =========================================================
type                                                   fields
=====================================================  =========================================================
sensor_msgs/Imu                                        qw qx qy qz gx gy gz ax ay az, cq.. cg.. ca.. (3 x 3 each)
sensor_msgs/NavSatFix                                  px py pz c00 .. c22: NED m about the recording's origin
sensor_msgs/MagneticField                              mx my mz (uT, body FRD)
sensor_msgs/Range                                      range (m)
nav_msgs/Odometry                                      px py pz qw qx qy qz cp.. (6 x 6), vx vy vz wx wy wz ct..
geometry_msgs/PoseWithCovarianceStamped                px py pz qw qx qy qz c.. (6 x 6: x y z roll pitch yaw)
geometry_msgs/TwistWithCovarianceStamped               vx vy vz wx wy wz c.. (6 x 6, body frame)
=====================================================  =========================================================

Odometry's and a twist's velocities are in the body frame (the message's ``child_frame_id``), as ROS has them.
A ``reference`` or ``truth`` topic (Odometry, PoseWithCovarianceStamped, PoseStamped) is written with the
state names of the project's systems: ``px py pz vx vy vz qw qx qy qz roll pitch yaw vbx vby vbz wx wy wz``
(NED velocity v, body velocity vb, body rates w), so ``fusion run`` compares ins and omni states alike.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from .rosbag_frames import (D_FLU, POSE_J, T_NE, TWIST_J, cov_names, euler_zyx, quat_matrix, ros_quat,
                            transform_cov, upper, world_quat)

T_TO_UT = 1e6   # sensor_msgs/MagneticField is in tesla; the project's magnetometer in uT


@dataclass(frozen=True)
class Kind:
    """How one message type becomes a row: ``fields``, ``units`` (header text), ``row(msg)`` -> values or
    None (the message carries nothing usable; ``why`` names it), ``covs``: the (start, n) field spans of its
    covariances (for the all-zero check), ``default``: the sensor name when the topic names none."""

    fields: tuple[str, ...]
    units: str
    row: Callable[[Any], np.ndarray | None]
    covs: tuple[tuple[int, int], ...] = ()
    why: str = ""
    default: str = "sensor"


def _vec(v) -> np.ndarray:
    return np.array([v.x, v.y, v.z], float)


def _cov(flat, n: int, J: np.ndarray) -> np.ndarray:
    return upper(transform_cov(np.asarray(flat, float).reshape(n, n), J))


def _imu(m) -> np.ndarray:
    q = ros_quat(m.orientation)
    q = world_quat(q) if np.linalg.norm(q) > 0 else np.zeros(4)   # an all-zero quaternion: no orientation
    return np.concatenate([q, D_FLU @ _vec(m.angular_velocity), D_FLU @ _vec(m.linear_acceleration),
                           _cov(m.orientation_covariance, 3, D_FLU), _cov(m.angular_velocity_covariance, 3, D_FLU),
                           _cov(m.linear_acceleration_covariance, 3, D_FLU)])


def _pose(p) -> np.ndarray:
    """px py pz qw qx qy qz of a geometry_msgs/Pose, NED / FRD-to-NED."""
    return np.concatenate([T_NE @ _vec(p.position), world_quat(ros_quat(p.orientation))])


def _pose_cov(m) -> np.ndarray:
    return np.concatenate([_pose(m.pose.pose), _cov(m.pose.covariance, 6, POSE_J)])


def _twist(t) -> np.ndarray:
    return np.concatenate([D_FLU @ _vec(t.linear), D_FLU @ _vec(t.angular)])


def _twist_cov(m) -> np.ndarray:
    return np.concatenate([_twist(m.twist.twist), _cov(m.twist.covariance, 6, TWIST_J)])


def _odometry(m) -> np.ndarray:
    return np.concatenate([_pose_cov(m), _twist_cov(m)])


def _mag(m) -> np.ndarray:
    return D_FLU @ _vec(m.magnetic_field) * T_TO_UT


def _range(m) -> np.ndarray | None:
    r = float(m.range)
    if not np.isfinite(r) or r < m.min_range or r > m.max_range:
        return None    # REP-117: -inf / +inf / outside [min, max] is no detection
    return np.array([r])


def _navsat(m) -> np.ndarray | None:
    if m.status.status < 0:   # STATUS_NO_FIX
        return None
    return np.concatenate([[m.latitude, m.longitude, m.altitude], _cov(m.position_covariance, 3, T_NE)])


POSE_FIELDS = ("px", "py", "pz", "qw", "qx", "qy", "qz")
TWIST_FIELDS = ("vx", "vy", "vz", "wx", "wy", "wz")
IMU_FIELDS = ("qw", "qx", "qy", "qz", "gx", "gy", "gz", "ax", "ay", "az",
              *cov_names("cq", 3), *cov_names("cg", 3), *cov_names("ca", 3))
GEO_FIELDS = ("lat", "lon", "alt", *cov_names("c", 3))        # as read; written as NAVSAT_FIELDS
NAVSAT_FIELDS = ("px", "py", "pz", *cov_names("c", 3))
POSE_COV_FIELDS = (*POSE_FIELDS, *cov_names("c", 6))
TWIST_COV_FIELDS = (*TWIST_FIELDS, *cov_names("c", 6))
ODOM_FIELDS = (*POSE_FIELDS, *cov_names("cp", 6), *TWIST_FIELDS, *cov_names("ct", 6))

KINDS: dict[str, Kind] = {
    "sensor_msgs/msg/Imu": Kind(IMU_FIELDS, "qw..qz body FRD to NED; g rad/s, a m/s^2 body FRD (specific force: "
                                "gravity not removed); cq rad^2 (roll pitch yaw), cg (rad/s)^2, ca (m/s^2)^2",
                                _imu, ((10, 3), (16, 3), (22, 3)), default="imu"),
    "sensor_msgs/msg/NavSatFix": Kind(GEO_FIELDS, "px py pz m NED about the recording's origin; c m^2 (NED)",
                                      _navsat, ((3, 3),), "without a fix (status -1)", default="gps"),
    "sensor_msgs/msg/MagneticField": Kind(("mx", "my", "mz"), "uT body FRD", _mag, default="mag"),
    "sensor_msgs/msg/Range": Kind(("range",), "m", _range, (), "outside [min_range, max_range] (no detection)",
                                  default="range"),
    "nav_msgs/msg/Odometry": Kind(ODOM_FIELDS, "p m NED, q body FRD to NED, cp (x y z roll pitch yaw); v m/s and "
                                  "w rad/s body FRD (child frame), ct", _odometry, ((7, 6), (34, 6)), default="odom"),
    "geometry_msgs/msg/PoseWithCovarianceStamped": Kind(POSE_COV_FIELDS, "p m NED, q body FRD to NED, c (x y z "
                                                        "roll pitch yaw)", _pose_cov, ((7, 6),), default="pose"),
    "geometry_msgs/msg/TwistWithCovarianceStamped": Kind(TWIST_COV_FIELDS, "v m/s, w rad/s body FRD; c",
                                                         _twist_cov, ((6, 6),), default="twist"),
}

REFERENCE_FIELDS = ("px", "py", "pz", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "roll", "pitch", "yaw",
                    "vbx", "vby", "vbz", "wx", "wy", "wz")


def _state_row(pose, twist=None) -> np.ndarray:
    p = _pose(pose)
    q = p[3:]
    vb = np.zeros(3) if twist is None else D_FLU @ _vec(twist.linear)
    w = np.zeros(3) if twist is None else D_FLU @ _vec(twist.angular)
    return np.concatenate([p[:3], quat_matrix(q) @ vb, q, euler_zyx(q), vb, w])


def state_row(msgtype: str, m) -> np.ndarray | None:
    """A ``reference`` / ``truth`` row (REFERENCE_FIELDS) of an Odometry or pose message, None for other types.
    A pose message has no velocity: its vx.. wz are written as 0 and the stream's fields stop at ``yaw``."""
    if msgtype == "nav_msgs/msg/Odometry":
        return _state_row(m.pose.pose, m.twist.twist)
    if msgtype in ("geometry_msgs/msg/PoseWithCovarianceStamped",):
        return _state_row(m.pose.pose)[:13]
    if msgtype == "geometry_msgs/msg/PoseStamped":
        return _state_row(m.pose)[:13]
    return None


def has_zero_cov(values: np.ndarray, kind: Kind) -> bool:
    """True when a covariance of the row ``values`` is all zeros (not the -1 'not provided' marker)."""
    for start, n in kind.covs:
        k = n * (n + 1) // 2
        if not np.any(values[start:start + k]):
            return True
    return False


def attribute(msg, path: str) -> float:
    """The number at a dotted attribute path of a message (``vector.x``, ``range``; ``a.0`` indexes an array)."""
    obj = msg
    for part in path.split("."):
        obj = obj[int(part)] if part.isdigit() else getattr(obj, part)
    return float(obj)
