"""The ``/fusion/pose`` message of the MCAP sink: an estimate as a ROS geometry_msgs/PoseWithCovarianceStamped in
REP-103 ENU world / FLU body, the inverse of what ``fusion import`` does to a bag (fusion.importers.rosbag_frames).

Position ``T_ne p``; attitude ``C_flu^enu = T_ne C_frd^ned D``; covariance of x y z and the rotation: an
``omni`` state's roll pitch yaw block mapped by diag(1, -1, -1); a quaternion state's small-angle attitude
error ``d theta = 2 vec(q^-1 (x) dq)`` (body frame, ``T P_qq T^T`` with ``T = 2 [rows x y z of L(q^-1)]``) mapped
by D. A state without an attitude gets the identity and 1e6 rad^2 (unknown, as ROS drivers say it).
"""
from __future__ import annotations

import numpy as np

from fusion.api import StateLayout
from fusion.importers.rosbag_frames import D_FLU, J_RPY, T_NE, matrix_quat, quat_matrix

UNKNOWN_VAR = 1e6


def _euler_matrix(r: float, p: float, y: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], [-sp, cp * sr, cp * cr]])


def _attitude(layout: StateLayout, x: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(C_frd^ned, A) with A (3, n): the attitude error (rad, FRD-compatible) as a linear map of the state error."""
    n = layout.n
    if all(b in layout for b in ("roll", "pitch", "yaw")):
        idx = [layout["roll"].start, layout["pitch"].start, layout["yaw"].start]
        A = np.zeros((3, n))
        A[[0, 1, 2], idx] = 1.0
        return _euler_matrix(*x[idx]), J_RPY @ A
    qb = next((b for b in layout.blocks if b.kind == "quaternion"), None)
    if qb is None:
        return None, None
    sl = layout[qb.name]
    q = x[sl] / np.linalg.norm(x[sl])
    w, a, b, c = q
    Linv = np.array([[w, a, b, c], [-a, w, c, -b], [-b, -c, w, a], [-c, b, -a, w]])   # L(q^-1) = L(q*)
    A = np.zeros((3, n))
    A[:, sl] = 2.0 * Linv[1:]
    return quat_matrix(q), D_FLU @ A


def pose_message(store, layout: StateLayout, x: np.ndarray, P: np.ndarray, t: float, frame_id: str):
    """The PoseWithCovarianceStamped (rosbags ``store`` type) of state x (n,) with covariance P (n, n) at t s."""
    T = store.types
    p_sl = layout["p"]
    Ap = np.zeros((3, layout.n))
    Ap[:, p_sl] = T_NE
    C, Ar = _attitude(layout, x)
    if C is None:
        q = np.array([1.0, 0.0, 0.0, 0.0])
        cov = np.zeros((6, 6))
        cov[:3, :3] = Ap @ P @ Ap.T
        cov[3:, 3:] = np.eye(3) * UNKNOWN_VAR
    else:
        q = matrix_quat(T_NE @ C @ D_FLU)
        A = np.vstack([Ap, Ar])
        cov = A @ P @ A.T
    ns = max(0, int(round(t * 1e9)))
    header = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
                                      frame_id=frame_id)
    pos = T_NE @ x[p_sl]
    pose = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=float(pos[0]), y=float(pos[1]), z=float(pos[2])),
        orientation=T["geometry_msgs/msg/Quaternion"](x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0])))
    return T[POSE](header=header, pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov.ravel()))


POSE = "geometry_msgs/msg/PoseWithCovarianceStamped"
