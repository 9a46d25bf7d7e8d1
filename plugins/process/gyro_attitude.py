"""Process ``gyro_attitude``: the attitude and gyro bias of an AHRS, driven by the IMU's rates.

State ``q:4 bw:3``: q the attitude (Hamilton, scalar first, body-to-navigation C_b^n, NED / FRD), bw the gyro
bias (rad/s, FRD). Input ``u = [ax ay az gx gy gz]`` (m/s^2, rad/s, FRD; the IMU line as the ``ins`` process
reads it): only the rates drive the state; the specific force is left to a ``gravity`` measurement (and to
the static alignment's levelling, :meth:`GyroAttitude.align`). Over dt, with ``w = u_g - bw`` held::

    q(k+1) = q(k) (x) exp(w dt / 2),   bw(k+1) = bw(k)

Noise from the data sheet's densities (as the ``ins`` process's q and bw blocks): the angle random walk N_w
enters q through ``dq/dw = Xi(q) dt / 2``, ``Q_qq = (dt / 4) Xi(q) N_w^2 Xi(q)^T`` (+ ``norm_sd^2 q q^T``
for a positive-definite P along the unobservable norm), the bias random walk ``Q_bw = N_bw^2 dt``.
The input is held over each interval (a sample's rate until the next one): when the rate changes by
``alpha dt`` a step, the held rate errs by up to that, the angle by ``alpha dt^2 / 2``; ``angular_accel_sd``
(sd of alpha, the body's angular acceleration) adds that variance, ``(alpha_sd dt^2 / 2)^2`` a step and axis,
to the angle noise (0 for a body that turns steadily). Those errors add up to a lag (~w dt / 2) more than to
a random walk, so a value above the motion's rms angular acceleration may be needed (docs/results/ahrs.md).
Jacobian (exact): ``dq'/dq = R(exp(w dt / 2))``, ``dq'/dbw = -(dt / 2) L(q) d exp(a) / da`` at ``a = w dt / 2``.
Runs of samples (the EKF's batched prediction, fusion.api.LinearisesInputRuns): :meth:`linearise_inputs`.
Earth rate is neglected (15 deg/h, below a MEMS gyro's bias instability).
"""
from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from pydantic import Field

from fusion import quaternion as quat
from fusion.api import Params, ProcessModel, StateLayout

# MPU-9250 (InvenSense PS-MPU-9250A-01 rev 1.1, table 1): gyro rate noise spectral density 0.01 deg/s/sqrt(Hz)
MPU9250_GYRO_ND = 0.01 * math.pi / 180.0          # rad/s/sqrt(Hz)
Density = float | tuple[float, float, float]


class GyroAttitudeParams(Params):
    """YAML parameters of ``gyro_attitude`` (SI units, FRD body frame)."""

    gyro_noise_density: Density = Field(MPU9250_GYRO_ND, description="gyro white noise (rad/s/sqrt(Hz)); "
                                        "= angle random walk (deg/sqrt(h)) / 60 * pi / 180")
    gyro_bias_rw: Density = Field(1e-5, description="gyro bias random walk (rad/s^2/sqrt(Hz))")
    angular_accel_sd: float = Field(0.0, ge=0, description="rad/s^2: sd of the body's angular acceleration; "
                                    "covers the error of holding a sample's rate over its interval (a rate "
                                    "that changes by alpha dt per step errs by alpha dt^2 / 2 in angle)")
    norm_sd: float = Field(1e-6, gt=0, description="sd along q itself per step (keeps P positive definite)")
    align_gyro_bias: bool = Field(True, description="the static start's mean rate becomes the gyro bias")


def _var(d: Density) -> np.ndarray:
    v = np.broadcast_to(np.asarray(d, dtype=float), (3,))
    if np.any(v < 0):
        raise ValueError(f"noise densities must be >= 0, got {d}")
    return v * v


class GyroAttitude(ProcessModel):
    """Attitude (q) and gyro bias (bw) driven by the gyro rates (module docstring)."""

    name: ClassVar[str] = "gyro_attitude"
    Params: ClassVar[type[Params]] = GyroAttitudeParams
    layout: StateLayout = StateLayout.parse("q:4:quaternion bw:3")
    input_dim: int = 6
    input_fields = ("ax", "ay", "az", "gx", "gy", "gz")   # m/s^2, rad/s, FRD body frame
    linear: bool = False

    def __init__(self, params: GyroAttitudeParams | None = None, context=None):
        super().__init__(params, context)
        self._nw = np.diag(_var(self.params.gyro_noise_density))       # type: ignore[attr-defined]
        self._nbw = np.diag(_var(self.params.gyro_bias_rw))            # type: ignore[attr-defined]
        self._norm_var = self.params.norm_sd ** 2                       # type: ignore[attr-defined]
        self._alpha_var = self.params.angular_accel_sd ** 2              # type: ignore[attr-defined]
        self._nw_diag = np.diag(self._nw).copy()

    @staticmethod
    def _delta(w: np.ndarray, dt: float) -> np.ndarray:
        """exp(w dt / 2) (..., 4) for body rates w (..., 3) rad/s."""
        a = np.asarray(w, dtype=float) * (0.5 * dt)
        s = np.sqrt(np.einsum("...i,...i->...", a, a))
        k = np.where(s > 1e-12, np.sin(s) / np.where(s > 1e-12, s, 1.0), 1.0 - s * s / 6.0)
        return np.concatenate([np.cos(s)[..., None], k[..., None] * a], axis=-1)

    def f(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """States (..., 7) after dt s with the held rates ``u[3:6]`` (rad/s, FRD) minus the bias."""
        x = np.asarray(x, dtype=float)
        y = np.array(x, copy=True)
        if u is None or dt == 0.0:
            return y
        w = np.asarray(u, dtype=float)[3:6] - x[..., 4:7]
        y[..., 0:4] = quat.multiply(x[..., 0:4], self._delta(w, dt))
        return y

    def _parts(self, q: np.ndarray, a: np.ndarray, dts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """F (k, 7, 7) and Q (k, 7, 7) of k steps from unit attitudes q (k, 4) with half rotation vectors
        a = (u_g - bw) dt / 2 (k, 3) over dts (k,) (module docstring), vectorised over the steps."""
        k = len(dts)
        s = np.sqrt(np.einsum("ki,ki->k", a, a))
        small = s < 1e-6
        ss = np.where(small, 1.0, s)
        sk = np.where(small, 1.0 - s * s / 6.0, np.sin(s) / ss)
        c = np.where(small, -1.0 / 3.0 + s * s / 30.0, (np.cos(s) - sk) / (ss * ss))
        D = np.empty((k, 4, 3))                                          # d exp(a) / da
        D[:, 0, :] = -sk[:, None] * a
        D[:, 1:, :] = sk[:, None, None] * np.eye(3) + c[:, None, None] * a[:, :, None] * a[:, None, :]
        d = np.concatenate([np.cos(s)[:, None], sk[:, None] * a], axis=1)
        L = quat.left_matrix(q)
        F = np.broadcast_to(np.eye(7), (k, 7, 7)).copy()
        F[:, 0:4, 0:4] = quat.right_matrix(d)
        F[:, 0:4, 4:7] = (-0.5 * dts)[:, None, None] * (L @ D)
        X = L[:, :, 1:]
        var = self._nw[None] * dts[:, None, None] + self._alpha_var * (dts ** 4 / 4.0)[:, None, None] * np.eye(3)
        Q = np.zeros((k, 7, 7))
        Q[:, 0:4, 0:4] = 0.25 * (X @ var @ np.swapaxes(X, 1, 2)) + self._norm_var * q[:, :, None] * q[:, None, :]
        Q[:, 4:7, 4:7] = self._nbw[None] * dts[:, None, None]
        return F, Q

    def _one(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> tuple[list, list, float]:
        """(q (4,) of x, d = exp(a) (4,), dt) in plain floats for one state x (7,) (the EKF's one-sample path)."""
        w, b, c, e, bx, by, bz = np.asarray(x, dtype=float).tolist()
        if u is None:
            return [w, b, c, e], [1.0, 0.0, 0.0, 0.0], 0.0
        _, _, _, gx, gy, gz = np.asarray(u, dtype=float).tolist()
        h = 0.5 * dt
        return [w, b, c, e], [(gx - bx) * h, (gy - by) * h, (gz - bz) * h], float(dt)

    def jacobian(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """F (7, 7) at x (7,) (exact; plain-float arithmetic, the same formulas as :meth:`_parts`)."""
        q, a, dt = self._one(x, u, dt)
        F = np.eye(7)
        if dt == 0.0:
            return F
        a1, a2, a3 = a
        s = math.sqrt(a1 * a1 + a2 * a2 + a3 * a3)
        k = math.sin(s) / s if s >= 1e-6 else 1.0 - s * s / 6.0
        cc = (math.cos(s) - k) / (s * s) if s >= 1e-6 else -1.0 / 3.0 + s * s / 30.0
        p0, p1, p2, p3 = math.cos(s), k * a1, k * a2, k * a3
        F[0:4, 0:4] = ((p0, -p1, -p2, -p3), (p1, p0, p3, -p2), (p2, -p3, p0, p1), (p3, p2, -p1, p0))
        q0, q1, q2, q3 = q
        L = np.array(((q0, -q1, -q2, -q3), (q1, q0, -q3, q2), (q2, q3, q0, -q1), (q3, -q2, q1, q0)))
        D = np.array(((-k * a1, -k * a2, -k * a3),
                      (k + cc * a1 * a1, cc * a1 * a2, cc * a1 * a3),
                      (cc * a2 * a1, k + cc * a2 * a2, cc * a2 * a3),
                      (cc * a3 * a1, cc * a3 * a2, k + cc * a3 * a3)))
        F[0:4, 4:7] = (-0.5 * dt) * (L @ D)
        return F

    def Q(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """Discrete process noise (7, 7) over dt s at x (7,) (module docstring)."""
        dt = max(float(dt), 0.0)
        q0, q1, q2, q3 = np.asarray(x, dtype=float)[0:4].tolist()
        n = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
        q = np.array((q0, q1, q2, q3)) / n
        q0, q1, q2, q3 = q.tolist()
        X = np.array(((-q1, -q2, -q3), (q0, -q3, q2), (q3, q0, -q1), (-q2, q1, q0)))
        var = self._nw_diag * dt + self._alpha_var * dt ** 4 / 4.0
        Qm = np.zeros((7, 7))
        Qm[0:4, 0:4] = 0.25 * ((X * var) @ X.T) + self._norm_var * np.outer(q, q)
        Qm[4:7, 4:7] = self._nbw * dt
        return Qm

    def linearise_inputs(self, x: np.ndarray, us: np.ndarray, dts: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x_k, F (k, 7, 7), Q (k, 7, 7)) of a run of input samples (fusion.api.LinearisesInputRuns): the
        attitudes chained sample by sample (normalised after each, as the filter does), F and Q vectorised."""
        x = np.asarray(x, dtype=float)
        dts = np.asarray(dts, dtype=float)
        a = (np.asarray(us, dtype=float)[:, 3:6] - x[4:7]) * (0.5 * dts)[:, None]
        s = np.sqrt(np.einsum("ki,ki->k", a, a))
        sk = np.where(s < 1e-6, 1.0 - s * s / 6.0, np.sin(s) / np.where(s < 1e-6, 1.0, s))
        ds = np.concatenate([np.cos(s)[:, None], sk[:, None] * a], axis=1).tolist()
        q = x[0:4] / math.sqrt(float(x[0:4] @ x[0:4]))
        w, b, c, e = q.tolist()
        qs = []
        for d0, d1, d2, d3 in ds:                       # q (x) d, renormalised (a serial chain: plain floats)
            qs.append((w, b, c, e))
            w, b, c, e = (w * d0 - b * d1 - c * d2 - e * d3, w * d1 + b * d0 + c * d3 - e * d2,
                          w * d2 - b * d3 + c * d0 + e * d1, w * d3 + b * d2 - c * d1 + e * d0)
            n = math.sqrt(w * w + b * b + c * c + e * e)
            w, b, c, e = w / n, b / n, c / n, e / n
        F, Q = self._parts(np.array(qs), a, dts)
        x1 = x.copy()
        x1[0:4] = (w, b, c, e)
        return x1, F, Q

    def align(self, x0: np.ndarray, P0: np.ndarray, u_mean: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Static start (``initial.align_s``): roll and pitch from the mean specific force ``u_mean[:3]``
        (a static accelerometer reads ``-C_n^b g_n``), yaw kept from x0 (a magnetometer's ``align`` sets it
        after this); with ``align_gyro_bias`` the mean rate becomes bw. P0 unchanged."""
        x0 = np.array(x0, dtype=float, copy=True)
        u_mean = np.asarray(u_mean, dtype=float)
        yaw = float(quat.to_euler(x0[0:4])[2]) if np.any(x0[0:4]) else 0.0
        x0[0:4] = quat.from_gravity(u_mean[:3], yaw)
        if self.params.align_gyro_bias:  # type: ignore[attr-defined]
            x0[4:7] = u_mean[3:6]
        return x0, np.array(P0, dtype=float, copy=True)
