"""The true motion at a set of times, and the attitude conversions it needs.

Attitude is given by aerospace Euler angles (yaw ``psi`` about down, then pitch ``theta`` about the new
right axis, then roll ``phi`` about forward), i.e. ``C_b^n = Rz(psi) Ry(theta) Rx(phi)``; the quaternion
is Hamilton, scalar first, body-to-navigation (DESIGN.md conventions). Body rates (rad/s, FRD) follow from
the Euler rates exactly::

    w_x = phi' - psi' sin(theta)
    w_y = theta' cos(phi) + psi' sin(phi) cos(theta)
    w_z = -theta' sin(phi) + psi' cos(phi) cos(theta)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


@dataclass(frozen=True)
class Kinematics:
    """True motion at times ``t`` (N,): NED position ``p``, velocity ``v``, acceleration ``a`` (N, 3; m,
    m/s, m/s^2), Euler angles ``euler`` (N, 3) = (roll, pitch, yaw) rad, their rates ``euler_rate`` (N, 3)
    rad/s, and the body angular rate ``w_b`` (N, 3) rad/s (FRD)."""

    t: np.ndarray
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    euler: np.ndarray
    euler_rate: np.ndarray

    @property
    def w_b(self) -> np.ndarray:
        return euler_rates_to_body(self.euler, self.euler_rate)

    @property
    def rotation(self) -> Rotation:
        """C_b^n as a scipy Rotation (N items)."""
        return euler_to_rotation(self.euler)

    @property
    def q(self) -> np.ndarray:
        """Quaternions (N, 4) ``[w x y z]`` body-to-NED, sign-continuous in time, starting with w >= 0."""
        return continuous_quaternions(self.rotation.as_quat(scalar_first=True))


def euler_to_rotation(euler: np.ndarray) -> Rotation:
    """C_b^n from (roll, pitch, yaw) (..., 3) in rad."""
    euler = np.asarray(euler, float)
    return Rotation.from_euler("ZYX", euler[..., ::-1])


def euler_rates_to_body(euler: np.ndarray, rates: np.ndarray) -> np.ndarray:
    """Body angular rate (..., 3) FRD from Euler angles and their time derivatives (roll, pitch, yaw)."""
    phi, theta = euler[..., 0], euler[..., 1]
    dphi, dtheta, dpsi = rates[..., 0], rates[..., 1], rates[..., 2]
    sp, cp, st, ct = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
    return np.stack([dphi - dpsi * st, dtheta * cp + dpsi * sp * ct, -dtheta * sp + dpsi * cp * ct], axis=-1)


def continuous_quaternions(q: np.ndarray) -> np.ndarray:
    """Flip signs so that consecutive quaternions (N, 4) have a non-negative dot product and q[0, 0] >= 0."""
    q = np.array(q, float)
    if len(q) == 0:
        return q
    if q[0, 0] < 0:
        q[0] = -q[0]
    dots = np.einsum("ij,ij->i", q[1:], q[:-1])
    flips = np.concatenate([[1.0], np.cumprod(np.where(dots < 0, -1.0, 1.0))])
    return q * flips[:, None]
