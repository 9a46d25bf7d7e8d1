"""Measurement ``imu``: a robot_localization IMU (``imuN``) sensor of the omni state.

Reads what ``fusion import`` writes for sensor_msgs/Imu (28 values: ``qw qx qy qz`` sensor FRD to NED, ``gx gy
gz`` rad/s and ``ax ay az`` m/s^2 sensor FRD, then the 3 x 3 covariances of orientation (roll pitch yaw),
angular velocity and acceleration as upper triangles; docs/ros.md). ROS's "not provided" (-1 as a
covariance's first element) leaves that part out of the message's update. The selected axes (``select``) of
roll pitch yaw, vroll vpitch vyaw and ax ay az are fused with the message's covariances as R
(robot_localization's floor of 1e-6 on each variance).

Mount (``mount_rotation`` C_m, sensor FRD -> body FRD, from /tf_static): attitude ``C_b^n = C_s^n C_m^T``,
rates and accelerations ``C_m`` times the sensor's, covariances rotated by C_m (robot_localization ignores the
lever arm of an IMU, and so does this model).

``remove_gravitational_acceleration`` (robot_localization's ``imuN_remove_gravitational_acceleration``): the
accelerometer's specific force plus gravity, ``a_b = f_b + C_b^n^T [0 0 g]`` (NED, g down), with the
message's own orientation as robot_localization does; without it the specific force is fused as the
acceleration (robot_localization's behaviour too). ``differential``: the orientation change between
consecutive messages as rates (Euler angles of ``C_{k-1}^T C_k`` / dt -> vroll vpitch vyaw); ``relative``: the
orientation relative to the first one.
"""
from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import Field

from fusion.api import BuildContext, MalformedMessage, Message, Observation
from fusion.importers.rosbag_frames import quat_matrix, unpack

from .rl_common import SelectionModel, rotate_cov, rpy_of, values, wrap
from .twist import MountParams


class ImuParams(MountParams):
    """YAML parameters of ``imu``."""

    remove_gravitational_acceleration: bool = Field(False, description="add gravity back to the specific force "
                                                    "(with the message's orientation) before fusing ax ay az")
    gravity: float = Field(9.80665, gt=0.0, le=30.0, description="m/s^2 (robot_localization's gravitational_"
                           "acceleration)")
    differential: bool = Field(False, description="fuse orientation changes as rates")
    relative: bool = Field(False, description="fuse the orientation relative to the first message's")


class Imu(SelectionModel):
    """robot_localization's IMU sensor on the omni state (module docstring): ``select``, ``mount_rotation``,
    ``remove_gravitational_acceleration``, ``differential``, ``relative``, ``two_d_mode``."""

    name: ClassVar[str] = "imu"
    Params = ImuParams

    def __init__(self, params: ImuParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        self._Cm = quat_matrix(np.asarray(self.params.mount_rotation, float))
        sel = set(self.params.indices())
        self._att = {i for i in sel if 3 <= i < 6}
        self._diff = {i + 6 for i in self._att}
        self._rates = {i for i in sel if 9 <= i < 12}
        self._acc = {i for i in sel if 12 <= i < 15}
        self._first: np.ndarray | None = None
        self._prev: tuple[float, np.ndarray, np.ndarray] | None = None

    def axes(self) -> tuple[int, ...]:
        sel = self.params.indices()
        att = [i + 6 if self.params.differential else i for i in sel if 3 <= i < 6]
        return tuple(att + [i for i in sel if i >= 9])

    def observe(self, message: Message) -> Observation | None:
        v = values(message, (28,), "imu")
        if not np.all(np.isfinite(v)):
            raise MalformedMessage(f"imu: non-finite value in {message.values!r}")
        Cm = self._Cm
        has_q = v[10] != -1.0 and np.linalg.norm(v[:4]) > 0
        parts = []
        C = None
        if has_q:
            C = quat_matrix(v[:4]) @ Cm.T
            S = rotate_cov(unpack(v[10:16], 3), Cm)
            parts += self._attitude(message.t, C, S)
        if v[16] != -1.0:
            parts.append((range(9, 12), Cm @ v[4:7], rotate_cov(unpack(v[16:22], 3), Cm), self._rates))
        if v[22] != -1.0 and self._acc:
            a = Cm @ v[7:10]
            if self.params.remove_gravitational_acceleration:
                if C is None:
                    raise MalformedMessage("imu: gravity removal needs the message's orientation, which it does not "
                                           "have (covariance -1 or an all-zero quaternion)")
                a = a + C.T @ np.array([0.0, 0.0, self.params.gravity])
            parts.append((range(12, 15), a, rotate_cov(unpack(v[22:28], 3), Cm), self._acc))
        return self.observation(message.t, parts)

    def _attitude(self, t: float, C: np.ndarray, S: np.ndarray) -> list:
        if self.params.relative:
            if self._first is None:
                self._first = C
            C = self._first.T @ C
        if not self.params.differential:
            return [(range(3, 6), rpy_of(C), S, self._att)]
        prev, self._prev = self._prev, (t, C, S)
        if prev is None or t <= prev[0]:
            return []
        dt = t - prev[0]
        return [(range(9, 12), wrap(rpy_of(prev[1].T @ C)) / dt, (S + prev[2]) / dt ** 2, self._diff)]
