"""Shared parts of the robot_localization-style measurement models (``pose``, ``twist``, ``imu``) of the ``omni``
state (fusion_plugins.process.omni): the 15-boolean per-axis selection, the bound selection model, the
message covariance as R with robot_localization's floor, and relative poses. Not a plugin module.

Each of these models measures a subset of the state directly, ``z = x[idx]`` (robot_localization's
measurement matrix is such a selection); what differs is how a message becomes that z (frames, gravity,
differences of consecutive poses).
"""
from __future__ import annotations

from typing import ClassVar, Sequence

import numpy as np
from pydantic import Field, field_validator

from fusion.api import BuildContext, ConfigError, MalformedMessage, MeasurementModel, Observation, Params
from fusion.importers.rosbag_frames import euler_zyx, matrix_quat, quat_matrix, unpack

NAMES = ("x", "y", "z", "roll", "pitch", "yaw", "vx", "vy", "vz", "vroll", "vpitch", "vyaw", "ax", "ay", "az")
ANGLES = frozenset((3, 4, 5))
TWO_D = frozenset((2, 3, 4, 8, 9, 10, 14))
#: robot_localization's floor on a measurement variance (a zero would make the update exact)
COVARIANCE_FLOOR = 1e-6


def wrap(a: np.ndarray) -> np.ndarray:
    """Angles (rad) into [-pi, pi)."""
    return (np.asarray(a, float) + np.pi) % (2 * np.pi) - np.pi


class SelectParams(Params):
    """The parameters every robot_localization-style model shares."""

    select: list[bool] | list[str] = Field(
        ..., description="robot_localization's *_config: 15 booleans in the state order x y z roll pitch yaw vx vy "
        "vz vroll vpitch vyaw ax ay az (world NED / body FRD), or the names of the axes to fuse")
    two_d_mode: bool = Field(False, description="never fuse z, roll, pitch, vz, vroll, vpitch, az")
    covariance_floor: float = Field(COVARIANCE_FLOOR, ge=0.0, description="a variance of the message below this "
                                    "is raised to it (robot_localization: 1e-6; an all-zero covariance otherwise "
                                    "makes the update exact)")

    @field_validator("select")
    @classmethod
    def _select(cls, v):
        if v and all(isinstance(b, bool) for b in v):
            if len(v) != 15:
                raise ValueError(f"15 booleans (x y z roll pitch yaw vx vy vz vroll vpitch vyaw ax ay az), got {len(v)}")
            return v
        bad = [n for n in v if n not in NAMES]
        if bad:
            raise ValueError(f"unknown axes {bad}: the axes are {' '.join(NAMES)}")
        return v

    def indices(self) -> tuple[int, ...]:
        """The selected state indices (two_d_mode's axes left out)."""
        v = self.select
        chosen = [i for i, b in enumerate(v) if b] if v and isinstance(v[0], bool) else [NAMES.index(n) for n in v]
        return tuple(i for i in sorted(set(chosen)) if not (self.two_d_mode and i in TWO_D))


class Selected(MeasurementModel):
    """``z = x[idx]`` for the omni state (angles wrapped in the residual); bound per observation by the models
    of this family. Linear: H is a selection matrix."""

    name: ClassVar[str] = "selected axes"
    linear = True
    carries_R = True

    def __init__(self, idx: Sequence[int], n: int = 15):
        super().__init__(Params())
        self.idx = np.asarray(idx, int)
        self.dim = len(self.idx)
        self._angles = np.array([i in ANGLES for i in self.idx])
        self._H = np.zeros((self.dim, n))
        self._H[np.arange(self.dim), self.idx] = 1.0
        self._H.setflags(write=False)

    def h(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(x, float)[..., self.idx]

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        return self._H

    def residual(self, z: np.ndarray, z_hat: np.ndarray) -> np.ndarray:
        d = np.asarray(z, float) - z_hat
        if self._angles.any():
            d = np.where(self._angles, wrap(d), d)
        return d


class SelectionModel(MeasurementModel):
    """Base of ``pose``, ``twist``, ``imu``: checks the state is omni's, keeps one Selected model per index set,
    and makes an Observation from (z over the 15 axes, R over the 15 axes, the axes the message has)."""

    carries_R = True
    linear = True

    def __init__(self, params=None, context: BuildContext | None = None):
        super().__init__(params, context)
        lay = self.context.layout
        if lay is None or lay.n != 15 or "vb" not in lay or "ab" not in lay:
            raise ConfigError(f"{self.name}: needs the omni process's 15-element state (p roll pitch yaw vb w ab)")
        self.idx = self.axes()
        if not self.idx:
            raise ConfigError(f"{self.name}: select names no axis this model fuses (after two_d_mode)")
        self.dim = len(self.idx)
        self._bound: dict[tuple[int, ...], Selected] = {}
        self._all = self.bound(self.idx)

    def h(self, x: np.ndarray) -> np.ndarray:
        """All the selected axes (..., dim); an observation binds the axes its message has (:meth:`bound`)."""
        return self._all.h(x)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        return self._all.jacobian(x)

    def residual(self, z: np.ndarray, z_hat: np.ndarray) -> np.ndarray:
        return self._all.residual(z, z_hat)

    def bound(self, idx: tuple[int, ...]) -> Selected:
        m = self._bound.get(idx)
        if m is None:
            m = self._bound[idx] = Selected(idx)
        return m

    def axes(self) -> tuple[int, ...]:
        """The state indices this model may fuse (default: the selected ones; a differential pose maps its
        pose axes onto the velocities)."""
        return self.params.indices()

    def observation(self, t: float, parts: Sequence[tuple[Sequence[int], np.ndarray, np.ndarray, set[int]]]
                    ) -> Observation | None:
        """The Observation of a message's ``parts``: (state indices, z, R, the indices of them to fuse) each,
        R block-diagonal across parts; None when no part has a fused axis. Variances below the floor are
        raised to it (negative ones taken by magnitude, as robot_localization does)."""
        from scipy.linalg import block_diag

        idx: list[int] = []
        zs, Rs = [], []
        for axes, z, R, wanted in parts:
            keep = [k for k, a in enumerate(axes) if a in wanted]
            if keep:
                idx += [axes[k] for k in keep]
                zs.append(np.asarray(z, float)[keep])
                Rs.append(np.asarray(R, float)[np.ix_(keep, keep)])
        if not idx:
            return None
        z = np.concatenate(zs)
        R = block_diag(*Rs)
        if not (np.all(np.isfinite(z)) and np.all(np.isfinite(R))):
            raise MalformedMessage(f"{self.name}: a value or covariance is not a finite number")
        R[np.diag_indices_from(R)] = np.maximum(np.abs(np.diag(R)), self.params.covariance_floor)
        return Observation(t, z, self.bound(tuple(idx)), R)


def values(message, sizes: Sequence[int], who: str) -> np.ndarray:
    """The message's numbers; MalformedMessage unless there are one of ``sizes`` of them."""
    v = message.floats()
    if v.ndim != 1 or v.size not in sizes:
        raise MalformedMessage(f"{who}: expected {' or '.join(map(str, sizes))} values (as fusion import writes a "
                               f"ROS message: docs/ros.md), got {v.size}")
    return v


def pose_parts(v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(p (3,), C (3, 3), covariance (6, 6)) of ``px py pz qw qx qy qz c00..c55``."""
    q = v[3:7]
    if not np.linalg.norm(q) > 0:
        raise MalformedMessage("a pose with an all-zero quaternion")
    return v[:3], quat_matrix(q), unpack(v[7:28], 6)


def rpy_of(C: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (rad) of C_b^n (ZYX)."""
    return euler_zyx(matrix_quat(C))


def rotate_cov(S: np.ndarray, A: np.ndarray) -> np.ndarray:
    """A S A^T."""
    return A @ S @ A.T
