"""Process ``omni``: robot_localization's 15-state omnidirectional model (its ``FilterBase`` / ``Ekf::predict``).

State (robot_localization's order), in the project's frames (NED world, FRD body):
``p:3`` position (m, world), ``roll pitch yaw`` (rad, ZYX Euler angles of C_b^n = Rz(yaw) Ry(pitch) Rx(roll)),
``vb:3`` body-frame velocity (m/s), ``w:3`` the rates ``vroll vpitch vyaw`` (rad/s, robot_localization's body
rates), ``ab:3`` body-frame acceleration (m/s^2). Over dt, with C = C(roll, pitch, yaw) and the Euler-rate
matrix E(roll, pitch) of robot_localization's transfer function:

.. math::
    p' = p + C (v_b \\Delta t + a_b \\Delta t^2 / 2), \\quad
    [\\phi\\ \\theta\\ \\psi]' = [\\phi\\ \\theta\\ \\psi] + E\\, w\\, \\Delta t, \\quad
    v_b' = v_b + a_b \\Delta t, \\quad w' = w, \\quad a_b' = a_b

    E = \\begin{bmatrix} 1 & \\sin\\phi \\tan\\theta & \\cos\\phi \\tan\\theta \\\\ 0 & \\cos\\phi & -\\sin\\phi \\\\
        0 & \\sin\\phi / \\cos\\theta & \\cos\\phi / \\cos\\theta \\end{bmatrix}

(no transport term in v_b: robot_localization's kinematics). Q = ``process_noise_covariance`` x dt (its
``delta * processNoiseCovariance``). The Jacobian is the exact derivative of f (robot_localization's
``transferFunctionJacobian``). ``two_d_mode``: z, roll, pitch, vz, vroll, vpitch and az are held at 0 (f and
F zero them) with ``two_d_variance`` each step, as robot_localization fuses a zero measurement of them.
Angles are not wrapped in the state (a sigma-point mean of points on both sides of +-pi would be wrong);
the measurement models wrap angle residuals. The input (role ``input``) is not used: every sensor of a
robot_localization system is a measurement.
"""
from __future__ import annotations

import numpy as np
from pydantic import Field, field_validator

from fusion.api import Block, Params, ProcessModel, StateLayout

#: robot_localization's default process_noise_covariance diagonal (ekf.yaml of the package), its state order
RL_PROCESS_NOISE = (0.05, 0.05, 0.06, 0.03, 0.03, 0.06, 0.025, 0.025, 0.04, 0.01, 0.01, 0.02, 0.01, 0.01, 0.015)
NAMES = ("x", "y", "z", "roll", "pitch", "yaw", "vx", "vy", "vz", "vroll", "vpitch", "vyaw", "ax", "ay", "az")
TWO_D = (2, 3, 4, 8, 9, 10, 14)      # z roll pitch vz vroll vpitch az


def layout() -> StateLayout:
    """``p:3 roll pitch yaw vb:3 w:3 ab:3`` (15 elements, robot_localization's order)."""
    return StateLayout([Block("p", 3), Block("roll", 1, "angle"), Block("pitch", 1, "angle"),
                        Block("yaw", 1, "angle"), Block("vb", 3), Block("w", 3), Block("ab", 3)])


def rotation(rpy: np.ndarray) -> np.ndarray:
    """C_b^n (..., 3, 3) = Rz(yaw) Ry(pitch) Rx(roll) of angles (..., 3) rad."""
    r, p, y = rpy[..., 0], rpy[..., 1], rpy[..., 2]
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.stack([np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
                     np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
                     np.stack([-sp, cp * sr, cp * cr], -1)], -2)


def euler_rates(rpy: np.ndarray) -> np.ndarray:
    """E (..., 3, 3): d(roll, pitch, yaw)/dt = E w, robot_localization's transfer function rows."""
    r, p = rpy[..., 0], rpy[..., 1]
    cr, sr, cp, tp = np.cos(r), np.sin(r), np.cos(p), np.tan(p)
    one, zero = np.ones_like(r), np.zeros_like(r)
    return np.stack([np.stack([one, sr * tp, cr * tp], -1), np.stack([zero, cr, -sr], -1),
                     np.stack([zero, sr / cp, cr / cp], -1)], -2)


def _derivatives(rpy: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """dC/d(roll, pitch, yaw) and dE/d(roll, pitch) (3 x 3 each) at angles rpy (3,)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    dC_dr = np.array([[0, cy * sp * cr + sy * sr, -cy * sp * sr + sy * cr],
                      [0, sy * sp * cr - cy * sr, -sy * sp * sr - cy * cr], [0, cp * cr, -cp * sr]])
    dC_dp = np.array([[-cy * sp, cy * cp * sr, cy * cp * cr], [-sy * sp, sy * cp * sr, sy * cp * cr],
                      [-cp, -sp * sr, -sp * cr]])
    dC_dy = np.array([[-sy * cp, -sy * sp * sr - cy * cr, -sy * sp * cr + cy * sr],
                      [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], [0, 0, 0]])
    tp, sec2 = np.tan(p), 1.0 / cp ** 2
    dE_dr = np.array([[0, cr * tp, -sr * tp], [0, -sr, -cr], [0, cr / cp, -sr / cp]])
    dE_dp = np.array([[0, sr * sec2, cr * sec2], [0, 0, 0], [0, sr * sp * sec2, cr * sp * sec2]])
    return [dC_dr, dC_dp, dC_dy], [dE_dr, dE_dp]


class OmniParams(Params):
    """YAML parameters of ``omni``."""

    process_noise_covariance: list[float] | list[list[float]] = Field(
        list(RL_PROCESS_NOISE), description="robot_localization's process_noise_covariance: 15 variances per s (the "
        "diagonal) or the 15 x 15 matrix, state order x y z roll pitch yaw vx vy vz vroll vpitch vyaw ax ay az "
        "(units m^2/s, rad^2/s, (m/s)^2/s, ...); Q = this x dt")
    two_d_mode: bool = Field(False, description="hold z, roll, pitch, vz, vroll, vpitch, az at 0 (planar robot)")
    two_d_variance: float = Field(1e-6, gt=0.0, le=1.0, description="variance those states keep each step in "
                                  "two_d_mode (keeps P positive definite)")

    @field_validator("process_noise_covariance")
    @classmethod
    def _shape(cls, v):
        a = np.asarray(v, float)
        if a.shape not in ((15,), (15, 15)):
            raise ValueError(f"needs 15 values (the diagonal) or a 15 x 15 matrix, got shape {a.shape}")
        if a.ndim == 2 and not np.allclose(a, a.T):
            raise ValueError("the 15 x 15 matrix must be symmetric")
        if np.any(np.diag(a) < 0) if a.ndim == 2 else np.any(a < 0):
            raise ValueError("variances must be >= 0")
        return v


class Omni(ProcessModel[OmniParams]):
    """robot_localization's omnidirectional 15-state model (module docstring): ``p:3 roll pitch yaw vb:3 w:3
    ab:3`` (m, rad, m/s body FRD, rad/s, m/s^2 body FRD; world NED). Params: ``process_noise_covariance`` (15
    or 15 x 15, per s), ``two_d_mode``."""

    name = "omni"
    Params = OmniParams

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        self.layout = layout()
        q = np.asarray(self.params.process_noise_covariance, float)
        self._Qc = np.diag(q) if q.ndim == 1 else q
        self._planar = np.zeros(15, bool)
        if self.params.two_d_mode:
            self._planar[list(TWO_D)] = True
            self._Qc = self._Qc.copy()
            self._Qc[self._planar, :] = 0.0
            self._Qc[:, self._planar] = 0.0

    def f(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """States (..., 15) predicted over dt s."""
        x = np.asarray(x, float)
        rpy, v, w, a = x[..., 3:6], x[..., 6:9], x[..., 9:12], x[..., 12:15]
        out = np.array(x, copy=True)
        out[..., 0:3] += np.einsum("...ij,...j->...i", rotation(rpy), v * dt + 0.5 * dt * dt * a)
        out[..., 3:6] += np.einsum("...ij,...j->...i", euler_rates(rpy), w) * dt
        out[..., 6:9] += a * dt
        if self.params.two_d_mode:
            out[..., self._planar] = 0.0
        return out

    def jacobian(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """F = df/dx (15, 15) at x (15,)."""
        x = np.asarray(x, float)
        rpy, v, w, a = x[3:6], x[6:9], x[9:12], x[12:15]
        C, E = rotation(rpy), euler_rates(rpy)
        dC, dE = _derivatives(rpy)
        s = v * dt + 0.5 * dt * dt * a
        F = np.eye(15)
        F[0:3, 6:9] = C * dt
        F[0:3, 12:15] = C * 0.5 * dt * dt
        for k in range(3):
            F[0:3, 3 + k] = dC[k] @ s
        F[3:6, 9:12] = E * dt
        for k in range(2):
            F[3:6, 3 + k] += dE[k] @ w * dt
        F[6:9, 12:15] = np.eye(3) * dt
        if self.params.two_d_mode:
            F[self._planar, :] = 0.0
        return F

    def Q(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """``process_noise_covariance * dt`` (15, 15); in two_d_mode the planar-held states get two_d_variance."""
        Q = self._Qc * max(dt, 0.0)
        if self.params.two_d_mode:
            Q = Q.copy()
            Q[self._planar, self._planar] = self.params.two_d_variance
        return Q
