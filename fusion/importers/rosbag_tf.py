"""Static transforms of a bag's ``/tf_static`` (tf2_msgs/TFMessage): sensor mountings on the robot.

A transform PARENT -> CHILD (translation t, rotation q) places the child frame in the parent: a point
``p_parent = C(q) p_child + t``. The mount of a sensor frame on the body frame (``base_link``) is the
composition along the tree; it is written as a lever arm (m, body FRD) and the rotation of the sensor's FRD
frame into the body's FRD frame (fusion.importers.rosbag_frames).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .rosbag_frames import D_FLU, body_quat, euler_zyx, quat_matrix, ros_quat


@dataclass(frozen=True)
class Transform:
    """CHILD in PARENT (ROS frames, FLU): translation (3,) m, rotation ``[w x y z]``."""

    parent: str
    child: str
    t: np.ndarray
    q: np.ndarray

    def as_args(self) -> str:
        """``X Y Z ROLL PITCH YAW`` (m, rad; ZYX Euler angles of the rotation, ROS FLU frames): the order of
        ``fusion import-config --tf PARENT CHILD X Y Z ROLL PITCH YAW``."""
        r, p, y = euler_zyx(self.q)
        return " ".join(f"{v + 0.0:.9g}" for v in (*self.t, r, p, y))   # + 0.0: no "-0"


def from_message(msg) -> list[Transform]:
    """The transforms of one tf2_msgs/TFMessage."""
    out = []
    for ts in msg.transforms:
        tr = ts.transform
        out.append(Transform(ts.header.frame_id.lstrip("/"), ts.child_frame_id.lstrip("/"),
                             np.array([tr.translation.x, tr.translation.y, tr.translation.z], float),
                             ros_quat(tr.rotation)))
    return out


def _chain(transforms: dict[str, Transform], base: str, frame: str) -> tuple[np.ndarray, np.ndarray] | None:
    """(C, t) of ``frame`` in ``base`` through the parents of ``frame``, or None when it does not lead to base."""
    C, t = np.eye(3), np.zeros(3)
    seen = set()
    while frame != base:
        if frame in seen or frame not in transforms:
            return None
        seen.add(frame)
        tr = transforms[frame]
        Cp = quat_matrix(tr.q)
        C, t = Cp @ C, Cp @ t + tr.t
        frame = tr.parent
    return C, t


def mount(transforms: dict[str, Transform], base: str, frame: str) -> tuple[np.ndarray, np.ndarray] | None:
    """(lever arm (3,) m body FRD, rotation ``[w x y z]`` sensor FRD -> body FRD) of ``frame`` on ``base``,
    or None when the static tree does not connect them (or ``frame`` is ``base`` itself)."""
    if not frame or frame == base:
        return None
    found = _chain(transforms, base, frame)
    if found is None:
        return None
    C, t = found
    from .rosbag_frames import matrix_quat

    return D_FLU @ t, body_quat(matrix_quat(C))
