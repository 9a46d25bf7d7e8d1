"""ROS frames (REP-103, REP-105) to the project's: ENU world / FLU body into NED world / FRD body.

ROS world frames (``map``, ``odom``) are right-handed with z up (x east, y north when geo-referenced: ENU), and
body frames (``base_link``, sensor frames) x forward, y left, z up (FLU). The project's are NED and FRD. With

    T_ne = [[0, 1, 0], [1, 0, 0], [0, 0, -1]]     (ENU -> NED: swap x and y, negate z)
    D    = diag(1, -1, -1)                         (FLU -> FRD: negate y and z)

a world vector is ``T_ne v``, a body vector ``D v``, an attitude ``C_frd^ned = T_ne C_flu^enu D``, and the ZYX
Euler angles become ``roll' = roll``, ``pitch' = -pitch``, ``yaw' = pi/2 - yaw`` (T_ne D = Rz(+90 deg), and D
conjugates Ry(t) into Ry(-t), Rz(t) into Rz(-t)). A covariance ``C`` of a vector ``v`` becomes ``J C J^T``
with the Jacobian of the map: ``T_ne`` or ``D`` for vectors, ``diag(1, -1, -1)`` for roll pitch yaw (the
rotational part of a ROS pose covariance, which robot_localization reads as roll pitch yaw variances).

Quaternions here are Hamilton ``[w x y z]`` (ROS messages store ``x y z w``: :func:`ros_quat`).
"""
from __future__ import annotations

import numpy as np

T_NE = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
D_FLU = np.diag([1.0, -1.0, -1.0])
J_RPY = np.diag([1.0, -1.0, -1.0])
POSE_J = np.block([[T_NE, np.zeros((3, 3))], [np.zeros((3, 3)), J_RPY]])      # x y z roll pitch yaw
TWIST_J = np.block([[D_FLU, np.zeros((3, 3))], [np.zeros((3, 3)), D_FLU]])    # vx vy vz wx wy wz (body)

#: Indices of the upper triangle of a symmetric n x n matrix, row by row (what the log's ``cNM`` fields hold).
UPPER3 = np.triu_indices(3)
UPPER6 = np.triu_indices(6)


def cov_names(prefix: str, n: int) -> tuple[str, ...]:
    """Field names of the upper triangle of an n x n covariance: ``c00 c01 .. c(n-1)(n-1)`` after ``prefix``."""
    rows, cols = np.triu_indices(n)
    return tuple(f"{prefix}{i}{j}" for i, j in zip(rows.tolist(), cols.tolist()))


def upper(C: np.ndarray) -> np.ndarray:
    """The upper triangle (n(n+1)/2,) of a symmetric matrix C (n, n), row by row."""
    return np.asarray(C, float)[np.triu_indices(C.shape[0])]


def unpack(values: np.ndarray, n: int) -> np.ndarray:
    """The symmetric n x n matrices (..., n, n) of upper triangles ``values`` (..., n(n+1)/2) (:func:`upper`)."""
    values = np.asarray(values, float)
    out = np.zeros(values.shape[:-1] + (n, n))
    r, c = np.triu_indices(n)
    out[..., r, c] = values
    out[..., c, r] = values
    return out


def ros_quat(msg_q) -> np.ndarray:
    """``[w x y z]`` of a geometry_msgs/Quaternion (stored ``x y z w``)."""
    return np.array([msg_q.w, msg_q.x, msg_q.y, msg_q.z], float)


def quat_matrix(q: np.ndarray) -> np.ndarray:
    """C (3, 3) of a Hamilton quaternion ``[w x y z]`` (normalised here; body-to-world)."""
    w, x, y, z = np.asarray(q, float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def matrix_quat(C: np.ndarray) -> np.ndarray:
    """Hamilton ``[w x y z]`` (w >= 0) of a rotation matrix C (3, 3), by scipy."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(C).as_quat()
    q = np.array([w, x, y, z])
    return -q if q[0] < 0 else q


def world_quat(q_enu_flu: np.ndarray) -> np.ndarray:
    """Attitude ``C_frd^ned`` ``[w x y z]`` of a ROS attitude ``C_flu^enu`` ``[w x y z]``."""
    return matrix_quat(T_NE @ quat_matrix(q_enu_flu) @ D_FLU)


def body_quat(q_flu_flu: np.ndarray) -> np.ndarray:
    """A rotation between two FLU frames (a mount: child in parent) as the same rotation between FRD frames."""
    return matrix_quat(D_FLU @ quat_matrix(q_flu_flu) @ D_FLU)


def euler_zyx(q: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (rad) of C = Rz(yaw) Ry(pitch) Rx(roll) for a quaternion ``[w x y z]``."""
    C = quat_matrix(q)
    return np.array([np.arctan2(C[2, 1], C[2, 2]), -np.arcsin(np.clip(C[2, 0], -1.0, 1.0)),
                     np.arctan2(C[1, 0], C[0, 0])])


def transform_cov(C: np.ndarray, J: np.ndarray) -> np.ndarray:
    """``J C J^T`` (a covariance re-expressed by the linear map J)."""
    return J @ np.asarray(C, float) @ J.T
