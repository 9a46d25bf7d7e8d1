"""The ``ins`` process for a run of IMU samples integrated in one step (the filters' ``predict_inputs``):
:func:`integrate_inputs` (the mean propagation by the compiled kernel, exact against sample-by-sample
:meth:`Ins.f <fusion_plugins.process.ins.Ins.f>`, the one numpy propagation), :func:`interval_noise` (the
process noise of the interval), and :func:`add_hold_noise` (the noise of a sample held over an IMU gap).
Kept apart from ins.py so that each module stays small; the maths is paper 000 eqs. 33-52.

States are handled component-first, ``(16, N)`` (one row per element, one column per sigma point), so
every product is one BLAS call on whole rows instead of N tiny ones.

:func:`integrate_inputs` and (isotropic noises) :func:`interval_noise` run the compiled kernel
``_ins_batch_kernel.c`` when it is built (fusion.kernels). Their references, tested against the kernel
(tests/models/test_ins_batch_kernel.py) and run without a C compiler or with ``FUSION_PURE_PYTHON=1``:
k calls of ``Ins.f`` and :func:`interval_noise_numpy`.
"""
from __future__ import annotations

import math

import numpy as np

from fusion import kernels
from fusion import quaternion as quat

__all__ = ["integrate_inputs", "interval_noise", "interval_noise_numpy", "add_hold_noise",
           "integrated_gm_variance", "gm_rate_noise", "K10T", "T16T"]

# [R(q).ravel(), |q|^2] = outer(q, q).ravel() @ K10 (one product gives the rotation matrix and its normaliser)
K10 = np.concatenate([quat.ROTATION_FORM, np.eye(16)[:, quat.NORM_TERMS].sum(axis=1, keepdims=True)], axis=1)
# The same forms transposed, for states stored component-first ((16, N): one row per element, one column
# per sigma point): every product below is then one BLAS gemm on whole rows instead of N tiny ones.
K10T = np.ascontiguousarray(K10.T)          # (10, 16): [R(q) rows (9), |q|^2] = K10T @ outer(q, q)
T16T = np.ascontiguousarray(quat.PRODUCT_FORM.T)     # (4, 16):  p (x) q = T16T @ outer(p, q)
# 4-point Gauss-Legendre on [-1, 1], mapped to [0, 1] below: numpy.polynomial.legendre.leggauss(4) to the
# last bit (tests/models/test_ins_batch_constants.py), tabulated because importing numpy.polynomial costs
# ~7 ms of every run's start-up
_GL_NODES = np.array([-0.8611363115940526, -0.33998104358485626, 0.33998104358485626, 0.8611363115940526])
_GL_WEIGHTS = np.array([0.34785484513745357, 0.6521451548625464, 0.6521451548625464, 0.34785484513745357])
_GL_NODES, _GL_WEIGHTS = 0.5 * (_GL_NODES + 1.0), 0.5 * _GL_WEIGHTS
_EYE15 = np.eye(15)
_EYE3 = np.eye(3)
_G16 = np.zeros((16, 15))                      # error state [dp dv dth dba dbw] -> state (q rows set per call)
_G16[0:6, 0:6] = np.eye(6)
_G16[10:16, 9:15] = np.eye(6)


# (4, 3): [s, s^2 / 2, s^3 / 6] at the Gauss-Legendre nodes s of [0, 1] (times [T, T^2, T^3] for [0, T])
_GL_POWERS = np.stack((_GL_NODES, 0.5 * _GL_NODES ** 2, _GL_NODES ** 3 / 6.0), axis=1)


_KERNEL = kernels.load("fusion_plugins.process._ins_batch_kernel")


def integrate_inputs(x: np.ndarray, us: np.ndarray, dts: np.ndarray, g_col: np.ndarray,
                     trapezoidal: bool) -> np.ndarray | None:
    """States x (..., 16) after the IMU samples ``us`` (k, 6) (m/s^2, rad/s, FRD), each held over ``dts``
    (k,) (s), without eta and Earth rate; ``g_col`` (3, 1) is g_n (m/s^2, NED): by the compiled kernel, or
    None when it is not loaded (the caller then integrates sample by sample with ``Ins.f``, the reference the
    kernel is tested against, tests/models/test_ins_batch_kernel.py). A new C-contiguous array.

    The kernel is vectorised over the samples too, which is exact because within the run the biases are
    constant (eqs. 51-52) and, without eta and Earth rate, the rotation increments do not depend on the
    attitude: with a_j = u_j - b_a, dq_j = [cos s_j, sinc s_j w_j dt_j / 2] (eqs. 43-49) and the prefix
    products P_j = dq_0 (x) ... (x) dq_{j-1}, q_j = q_0 (x) P_j and C_j = C(q_0) C(P_j), so with
    b_j = C(P_j) a_j (Euler) or (C(P_j) + C(P_j+1)) a_j / 2 (trapezoidal)::

        v_k = v_0 + C(q_0) sum_j b_j dt_j + g_n T
        p_k = p_0 + v_0 T + C(q_0) sum_j b_j w_j + g_n sum_j w_j,   w_j = dt_j r_j (+ dt_j^2 / 2)

    with T = sum dt_j and r_j = sum_{i>j} dt_i."""
    if _KERNEL is None:
        return None
    X = np.ascontiguousarray(x, dtype=float)
    if X.shape[-1:] != (16,):
        raise ValueError(f"integrate_inputs: states must be (..., 16), got shape {X.shape}")
    out = np.empty(X.shape)
    _KERNEL.integrate(X.reshape(-1, 16), np.ascontiguousarray(us, dtype=float), np.ascontiguousarray(dts, dtype=float),
                      np.ascontiguousarray(g_col, dtype=float).reshape(3), bool(trapezoidal), out.reshape(-1, 16))
    return out


def interval_noise(x0: np.ndarray, x1: np.ndarray, dts: np.ndarray, g_n: np.ndarray, var_a: np.ndarray,
                   var_w: np.ndarray, var_ba: np.ndarray, var_bw: np.ndarray, qc_diag: np.ndarray | None,
                   qnv: float) -> np.ndarray:
    """Process noise (16, 16) of the interval T = sum dts from the means x0 (before) and x1 (after);
    ``var_*`` the noise densities squared (3,), ``qc_diag`` their diagonal when all are isotropic, ``qnv``
    the quaternion-norm variance per sample.

    The noise of the whole interval T = sum dts, propagated through the linearised error dynamics
    rather than summed per sample (a sum would miss that early accelerometer noise moves p by the
    end, and that gyro noise tilts the specific force into v). Error state e = [dp, dv, dth, dba, dbw]
    (dth a navigation-frame attitude error, q_true = exp(dth / 2) (x) q), constant over the interval::

        de/dt = F e + noise,   F: dp <- dv (I),  dv <- dth (-[f_n x]),  dv <- dba (-C),  dth <- dbw (-C)
        Q_c = blkdiag(0, C N_a^2 C^T, C N_w^2 C^T, N_ba^2, N_bw^2)
        Q_e = int_0^T e^{F s} Q_c e^{F^T s} ds = sum_{i,j<=3} F^i Q_c F^j^T T^{i+j+1} / (i! j! (i+j+1))

    exact for constant F because F^4 = 0 (the chain dbw -> dth -> dv -> dp): the integrand is a
    polynomial of degree 6 in s, integrated exactly by 4-point Gauss-Legendre quadrature. f_n is the
    mean specific force in the navigation frame, (v1 - v0) / T - g_n; C the attitude at mid-interval;
    dth maps to q at the end as ``dq = [0, dth] (x) q1 / 2``. For one sample of dt this is :meth:`Q` plus the
    couplings of order dt^2 and higher that :meth:`Q` leaves to the propagation of later steps.

    With isotropic noises (``qc_diag`` given) by the compiled kernel when it is loaded, else
    :func:`interval_noise_numpy`."""
    if _KERNEL is not None and qc_diag is not None:          # the compiled kernel (isotropic noises)
        Qm = np.empty((16, 16))
        _KERNEL.interval_noise(np.ascontiguousarray(x0, dtype=float), np.ascontiguousarray(x1, dtype=float),
                               np.ascontiguousarray(dts, dtype=float), np.ascontiguousarray(g_n, dtype=float),
                               np.ascontiguousarray(qc_diag, dtype=float), float(qnv), Qm)
        return Qm
    return interval_noise_numpy(x0, x1, dts, g_n, var_a, var_w, var_ba, var_bw, qc_diag, qnv)


def interval_noise_numpy(x0: np.ndarray, x1: np.ndarray, dts: np.ndarray, g_n: np.ndarray, var_a: np.ndarray,
                         var_w: np.ndarray, var_ba: np.ndarray, var_bw: np.ndarray, qc_diag: np.ndarray | None,
                         qnv: float) -> np.ndarray:
    """:func:`interval_noise` in numpy: the reference of the compiled kernel, and the general case
    (non-isotropic noises) it leaves to numpy."""
    dts = np.asarray(dts, dtype=float)
    T = float(dts.sum())
    x0 = np.asarray(x0, dtype=float)
    x1 = np.asarray(x1, dtype=float)
    fn = (x1[3:6] - x0[3:6]) / T - g_n
    qm = x0[6:10] + x1[6:10]
    Rn = K10T @ (qm[:, None] * qm).reshape(16)
    C = (Rn[:9] / Rn[9]).reshape(3, 3)                       # C_b^n at mid-interval
    FF = np.zeros((3, 15, 15))                               # F, F^2, F^3
    F = FF[0]
    F[0:3, 3:6] = _EYE3
    F[3:6, 6:9] = ((0.0, fn[2], -fn[1]), (-fn[2], 0.0, fn[0]), (fn[1], -fn[0], 0.0))   # -[f_n x]
    F[3:6, 9:12] = F[6:9, 12:15] = -C
    np.matmul(F, F, out=FF[1])
    np.matmul(FF[1], F, out=FF[2])
    # Phi(s_m) = e^{F s_m} = I + F s + F^2 s^2 / 2 + F^3 s^3 / 6 at the 4 Gauss-Legendre nodes s_m
    Phi = ((_GL_POWERS * (T, T * T, T * T * T)) @ FF.reshape(3, 225)).reshape(4, 15, 15)
    Phi += _EYE15
    q = x1[6:10]
    q0, q1, q2, q3 = q
    G = _G16.copy()
    G[6:10, 6:9] = ((-0.5 * q1, -0.5 * q2, -0.5 * q3), (0.5 * q0, 0.5 * q3, -0.5 * q2),
                    (-0.5 * q3, 0.5 * q0, 0.5 * q1), (0.5 * q2, -0.5 * q1, 0.5 * q0))   # [0, dth] (x) q / 2
    GPhi = G @ Phi                                           # (4, 16, 15)
    w = _GL_WEIGHTS * T
    if qc_diag is not None:                                  # isotropic white noises: Q_c diagonal
        A = GPhi * np.sqrt(np.multiply.outer(w, qc_diag))[:, None, :]
        A = A.transpose(1, 0, 2).reshape(16, 60)
        Qm = A @ A.T                                         # sum_m w_m G Phi_m Q_c Phi_m^T G^T
    else:
        Qc = np.zeros((15, 15))
        Qc[3:6, 3:6] = (C * var_a) @ C.T
        Qc[6:9, 6:9] = (C * var_w) @ C.T
        Qc[9:12, 9:12] = np.diag(var_ba)
        Qc[12:15, 12:15] = np.diag(var_bw)
        L = (GPhi @ Qc) * w[:, None, None]
        Qm = L.transpose(1, 0, 2).reshape(16, 60) @ GPhi.transpose(0, 2, 1).reshape(60, 16)
        Qm = 0.5 * (Qm + Qm.T)
    if qnv:
        Qm[6:10, 6:10] += np.outer(q, q) * (qnv * len(dts) / (q @ q))
    return Qm


def integrated_gm_variance(sd: float, tau: float, e: float) -> float:
    """Variance of the integral over ``e`` s of a first-order Gauss-Markov process of stationary sd ``sd``
    and correlation time ``tau`` (s), started in its stationary state: ``2 sd^2 tau^2 (x - 1 + exp(-x))``
    with x = e / tau; ``sd^2 e^2`` for e << tau (an unknown constant), ``2 sd^2 tau e`` for e >> tau (a
    random walk). The series near 0, where the closed form cancels."""
    if e <= 0.0 or sd == 0.0:
        return 0.0
    x = e / tau
    h = x * x * (0.5 - x / 6.0 + x * x / 24.0) if x < 1e-3 else x - 1.0 + math.exp(-x)
    return 2.0 * sd * sd * tau * tau * h


def gm_rate_noise(sd: float, tau: float, e0: float, e1: float) -> tuple[float, float, float]:
    """(vv, pv, pp): the noise that a velocity error with :func:`integrated_gm_variance` G as its variance
    adds from ``e0`` to ``e1`` s, and its pull on the position, modelled as a white noise of intensity
    q(t) = dG/dt = 2 sd^2 tau (1 - exp(-t / tau)) (a Markov model with the known time since the hold began):
    ``vv = int q``, ``pv = int q (e1 - t)``, ``pp = int q (e1 - t)^2`` over [e0, e1] (closed forms). The
    velocity's variance is then G exactly, and the noise of a gap the same however it is cut into
    predictions; the position's is ``int_0^e q (e - t)^2 dt``, the true double integral for e >> tau and
    2/3 of it for e << tau (an unknown constant acceleration), where the gap is short anyway."""
    d = e1 - e0
    if d <= 0.0 or sd == 0.0:
        return 0.0, 0.0, 0.0
    c = 2.0 * sd * sd * tau
    a0, a1 = math.exp(-e0 / tau), math.exp(-e1 / tau)
    vv = integrated_gm_variance(sd, tau, e1) - integrated_gm_variance(sd, tau, e0)
    pv = c * (0.5 * d * d - tau * tau * ((d / tau - 1.0) * a0 + a1))
    pp = c * (d * d * d / 3.0 - (tau * a0 * (d * d - 2.0 * tau * d + 2.0 * tau * tau) - 2.0 * tau ** 3 * a1))
    return vv, max(pv, 0.0), max(pp, 0.0)


def add_hold_noise(Qm: np.ndarray, q: np.ndarray, e0: float, e1: float, accel_sd: float, yaw_rate_sd: float,
                   tilt_rate_sd: float, tau: float, max_angle_sd: float = math.inf) -> None:
    """Add to Qm (16, 16), in place, the noise of coasting from ``e0`` to ``e1`` s past ``hold_after`` (an
    IMU gap: the mean keeps its attitude and velocity, ``p += v e``): the vehicle's own motion, which no
    sample reports, in the navigation frame (NED). The acceleration (sd ``accel_sd``, m/s^2, each axis) and
    the rotation rates about north and east (``tilt_rate_sd``) and down (``yaw_rate_sd``, rad/s) are
    first-order Gauss-Markov processes of correlation time ``tau`` s, so the velocity and attitude errors
    of the coast are their integrals (:func:`integrated_gm_variance` G): a missed sample or two cost
    nothing (G ~ sd^2 e^2), a long gap grows like a random walk (G ~ 2 sd^2 tau e).

    A gap is usually cut into several predictions by the other sensors' messages; each adds what accrued
    over its own stretch, ``G(e1) - G(e0)`` (the run tells the model how long the sample has been held,
    fusion.api.HoldsInput), so the variances a gap adds are those of the whole gap however it is cut.
    The position follows through :func:`gm_rate_noise` (the same invariance). The attitude variance one prediction adds is at most
    ``max_angle_sd^2`` (rad^2) per axis: what a linearised quaternion block can carry in one step (a long
    pause of every stream is one prediction); over a gap that measurements cut into steps it may grow
    further, the measurements in between holding what they observe. Separate tilt and
    heading because a vehicle turns freely but stays near level: an isotropic attitude noise let the
    magnetometer, the only attitude measurement during a gap, tilt the estimate (one field vector leaves
    the rotation about itself unobserved), and the EKF diverged when the IMU came back
    (docs/results/imu_dropout.md). q (4,) is the attitude the quaternion block is expressed at."""
    d = e1 - e0
    if d <= 0.0:
        return
    vv, pv, pp = gm_rate_noise(accel_sd, tau, e0, e1)
    Qm[3:6, 3:6] += _EYE3 * vv
    Qm[0:3, 3:6] += _EYE3 * pv
    Qm[3:6, 0:3] += _EYE3 * pv
    Qm[0:3, 0:3] += _EYE3 * pp
    cap = max_angle_sd * max_angle_sd

    def added(sd: float) -> float:
        return min(integrated_gm_variance(sd, tau, e1) - integrated_gm_variance(sd, tau, e0), cap)

    vt, vy = added(tilt_rate_sd), added(yaw_rate_sd)
    q0, q1, q2, q3 = (float(c) for c in q)
    Xi = np.array(((-q1, -q2, -q3), (q0, q3, -q2), (-q3, q0, q1), (q2, -q1, q0)))   # [0, v] (x) q = Xi v
    Qm[6:10, 6:10] += (Xi * (0.25 * np.array((vt, vt, vy)))) @ Xi.T
