"""Measurement ``twist``: a robot_localization twist (``twistN``) sensor of the omni state.

Reads what ``fusion import`` writes for geometry_msgs/TwistWithCovarianceStamped (27 values: ``vx vy vz wx wy
wz`` body FRD and the upper triangle of their 6 x 6 covariance) or the twist of a nav_msgs/Odometry (55
values: the pose first, docs/ros.md). The selected axes of vx vy vz vroll vpitch vyaw (``select``) are fused
with the message's covariance as R (robot_localization's floor of 1e-6 on each variance).

A sensor mounted off the body (``mount_rotation`` sensor FRD -> body FRD, ``lever_arm`` m body FRD; what
``fusion import`` reads from /tf_static) is brought to the body as robot_localization does:
``w_b = C_m w_s``, ``v_b = C_m v_s - w_b x r`` (the lever arm's own velocity taken out), covariance
rotated by C_m.
"""
from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import Field

from fusion.api import BuildContext, MalformedMessage, Message, Observation
from fusion.importers.rosbag_frames import quat_matrix, unpack

from .rl_common import SelectionModel, SelectParams, rotate_cov, values


class MountParams(SelectParams):
    """YAML parameters of ``twist`` (and, with more, of ``imu``)."""

    mount_rotation: tuple[float, float, float, float] = Field(
        (1.0, 0.0, 0.0, 0.0), description="[w x y z]: the sensor's FRD frame in the body's FRD frame (a "
        "/tf_static mount, as fusion import writes it in the header)")
    lever_arm: tuple[float, float, float] = Field((0.0, 0.0, 0.0), description="m, body FRD: the sensor's position")


class Twist(SelectionModel):
    """robot_localization's twist sensor on the omni state (module docstring): ``select``, ``mount_rotation``,
    ``lever_arm``, ``two_d_mode``, ``covariance_floor``."""

    name: ClassVar[str] = "twist"
    Params = MountParams

    def __init__(self, params: MountParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        self._C = quat_matrix(np.asarray(self.params.mount_rotation, float))
        self._r = np.asarray(self.params.lever_arm, float)
        self._wanted = set(self.idx)

    def axes(self) -> tuple[int, ...]:
        return tuple(i for i in self.params.indices() if 6 <= i < 12)

    def observe(self, message: Message) -> Observation | None:
        v = values(message, (27, 55), "twist")
        if v.size == 55:
            v = v[28:]
        if not np.all(np.isfinite(v)):
            raise MalformedMessage(f"twist: non-finite value in {message.values!r}")
        w = self._C @ v[3:6]
        vb = self._C @ v[:3] - np.cross(w, self._r)
        A = np.zeros((6, 6))
        A[:3, :3] = A[3:, 3:] = self._C
        R = rotate_cov(unpack(v[6:27], 6), A)
        return self.observation(message.t, [(range(6, 12), np.concatenate([vb, w]), R, self._wanted)])
