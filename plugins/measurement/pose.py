"""Measurement ``pose``: a robot_localization pose (``poseN``) or odometry (``odomN``) sensor of the omni state.

Reads what ``fusion import`` writes for geometry_msgs/PoseWithCovarianceStamped (28 values: ``px py pz qw qx qy
qz`` and the 6 x 6 covariance of x y z roll pitch yaw, upper triangle) and nav_msgs/Odometry (55 values: that
pose, then ``vx vy vz wx wy wz`` body FRD and their 6 x 6 covariance): world NED, body FRD (docs/ros.md).
The selected axes (``select``: robot_localization's 15-boolean ``*_config``) of x y z roll pitch yaw come from
the pose, those of vx..vyaw from an Odometry's twist; R is the message's covariance (robot_localization's
floor of 1e-6 on each variance). Modes (robot_localization's):

- ``relative``: each pose relative to the first one, ``T0^-1 T`` (position ``C0^T (p - p0)``, attitude
  ``C0^T C``), so a sensor whose world frame is not the filter's starts at the filter's origin;
- ``differential``: consecutive poses turned into body velocities, ``dp = C_{k-1}^T (p_k - p_{k-1}) / dt`` for
  x y z -> vx vy vz and the Euler angles of ``C_{k-1}^T C_k`` / dt for roll pitch yaw -> vroll vpitch vyaw,
  with covariance ``(R_k + R_{k-1}) / dt^2`` (position part rotated into the earlier body frame). The first
  message of the run gives no update.

The pose of the message is taken as the body's (``base_link``): a sensor frame off the body is not moved.
"""
from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import Field

from fusion.api import BuildContext, MalformedMessage, Message, Observation

from .rl_common import SelectionModel, SelectParams, pose_parts, rotate_cov, rpy_of, values, wrap
from fusion.importers.rosbag_frames import unpack


class PoseParams(SelectParams):
    """YAML parameters of ``pose``."""

    differential: bool = Field(False, description="fuse the change between consecutive poses as body velocities")
    relative: bool = Field(False, description="fuse each pose relative to the first one")


class Pose(SelectionModel):
    """robot_localization's pose / odometry sensor on the omni state (module docstring). ``select`` 15 booleans
    (or axis names), ``differential``, ``relative``, ``two_d_mode``, ``covariance_floor``."""

    name: ClassVar[str] = "pose"
    Params = PoseParams

    def __init__(self, params: PoseParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        self._first: tuple[np.ndarray, np.ndarray] | None = None
        self._prev: tuple[float, np.ndarray, np.ndarray, np.ndarray] | None = None
        sel = set(self.params.indices())
        self._pose_wanted = {i for i in sel if i < 6}
        self._diff_wanted = {i + 6 for i in self._pose_wanted}
        self._twist_wanted = {i for i in sel if 6 <= i < 12}

    def axes(self) -> tuple[int, ...]:
        sel = self.params.indices()
        pose = [i + 6 if self.params.differential else i for i in sel if i < 6]
        return tuple(pose + [i for i in sel if 6 <= i < 12])

    def observe(self, message: Message) -> Observation | None:
        v = values(message, (28, 55), "pose")
        p, C, S = pose_parts(v)
        parts = []
        if self.params.relative:
            if self._first is None:
                self._first = (p, C)
            p0, C0 = self._first
            p, C = C0.T @ (p - p0), C0.T @ C
            A = np.eye(6)
            A[:3, :3] = C0.T
            S = rotate_cov(S, A)
        if self.params.differential:
            prev, self._prev = self._prev, (message.t, p, C, S)
            if prev is not None and message.t > prev[0]:
                dt = message.t - prev[0]
                Cp = prev[2]
                z = np.concatenate([Cp.T @ (p - prev[1]), wrap(rpy_of(Cp.T @ C))]) / dt
                A = np.eye(6)
                A[:3, :3] = Cp.T
                R = rotate_cov(S + prev[3], A) / dt ** 2
                parts.append((range(6, 12), z, R, self._diff_wanted))
        else:
            parts.append((range(6), np.concatenate([p, rpy_of(C)]), S, self._pose_wanted))
        if v.size == 55 and self._twist_wanted:
            parts.append((range(6, 12), v[28:34], unpack(v[34:55], 6), self._twist_wanted))
        if not np.all(np.isfinite(v)):
            raise MalformedMessage(f"pose: non-finite value in {message.values!r}")
        return self.observation(message.t, parts)
