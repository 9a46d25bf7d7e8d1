"""The EKF's run of IMU samples for the paper-002 state sets (10 and 22 states, Euler, no eta or Earth rate):
means, Jacobians and process noise of k samples in one vectorised pass (``InsStates.linearise_inputs``).

Why not k calls of ``InsStates._step``: one scalar step is Python overhead, most of a 50 Hz replay's time.
Within a run between two measurements the biases and scale factors do not change (their mean is kept by
the prediction), so every sample's corrected input, its rotation increment ``dq`` and the blocks of F that
depend on it are known at once and computed over the whole run; only the attitude chain
``q_{j+1} = normalize(q_j (x) dq_j)`` is sequential (four-element products in plain floats). Velocity and
position follow by running sums in the same order as the per-sample additions. The numbers are those of
``_step`` / ``_noise`` to rounding (tests/models/test_ins_linearise.py).

Compiled: when the C kernel ``fusion_plugins.process._ins_run_kernel`` (_ins_run_kernel.c, setup.py KERNELS)
is built and not disabled (``FUSION_PURE_PYTHON=1``, fusion/kernels.py), :func:`linearise_run` runs it: the
same operations sample by sample in C (no per-call numpy overhead), the same
numbers to the last bit or two (tests/models/test_ins_run_kernel.py). :func:`linearise_run_numpy` is the
reference and the fallback.
"""
from __future__ import annotations

import math

import numpy as np

from fusion import kernels
from fusion import quaternion as quat

__all__ = ["linearise_run", "linearise_run_numpy", "KERNEL"]

#: the compiled kernel (_ins_run_kernel.c), or None: not built, or FUSION_PURE_PYTHON=1 at import
KERNEL = kernels.load("fusion_plugins.process._ins_run_kernel")

# The structure constants of fusion.quaternion, arranged so that each block of F is one product over the
# whole run (a handful of numpy calls instead of one per matrix element: the blocks are tiny, so call
# overhead is the cost):
#   R(q) (k, 9)          = (q q^T) (k, 16) @ ROTATION_FORM (16, 9)       (C_b^n = R(q) / |q|^2)
#   dR/dq a (k, 3 x 4)   = (q a^T) (k, 12) @ _DRA_OF_QA (12, 12),   dR_rc/dq_j = sum_l (K + K^T)[j, l, rc] q_l
#   R(p), L(q) (k, 16)   = p (k, 4) @ _RIGHT / _LEFT (4, 16):       q (x) p = R(p) q = L(q) p
_K = quat.ROTATION_FORM.reshape(4, 4, 3, 3)
_R_OF_QQ = quat.ROTATION_FORM
_DRA_OF_QA = np.ascontiguousarray((_K + _K.transpose(1, 0, 2, 3)).transpose(1, 3, 2, 0).reshape(12, 12))
_T = quat.PRODUCT_FORM.reshape(4, 4, 4)          # [left, right, out]: (a (x) b)_i = a_j b_m T[j, m, i]
_RIGHT = np.ascontiguousarray(_T.transpose(1, 2, 0).reshape(4, 16))   # [m, (i, j)] = T[j, m, i]
_LEFT = np.ascontiguousarray(_T.transpose(0, 2, 1).reshape(4, 16))    # [m, (i, j)] = T[m, j, i]
_I3 = np.eye(3)
_I4 = np.eye(4)
_EYES: dict[tuple[int, int], np.ndarray] = {}


def _identities(k: int, n: int) -> np.ndarray:
    """k identity matrices (k, n, n), a new array (copied from a cached one: one call instead of two)."""
    E = _EYES.get((k, n))
    if E is None:
        if len(_EYES) > 64:
            _EYES.clear()
        E = _EYES[(k, n)] = np.broadcast_to(np.eye(n), (k, n, n)).copy()
    return E.copy()


def _chain(q: list[float], dq: np.ndarray, unit: bool) -> np.ndarray:
    """Attitudes before each sample and after the last: (k + 1, 4); q_{j+1} = q_j (x) dq_j, renormalised
    when ``unit`` (the filter renormalises the predicted mean)."""
    out = [q]
    q0, q1, q2, q3 = q
    for p0, p1, p2, p3 in dq.tolist():
        q0, q1, q2, q3 = (q0 * p0 - q1 * p1 - q2 * p2 - q3 * p3, q0 * p1 + q1 * p0 + q2 * p3 - q3 * p2,
                          q0 * p2 - q1 * p3 + q2 * p0 + q3 * p1, q0 * p3 + q1 * p2 - q2 * p1 + q3 * p0)
        if unit:
            r = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
            q0, q1, q2, q3 = q0 / r, q1 / r, q2 / r, q3 / r
        out.append([q0, q1, q2, q3])
    return np.array(out)


def linearise_run(x: np.ndarray, us: np.ndarray, dts: np.ndarray, g: float, unit: bool,
                  Q_base: np.ndarray, var_w: float, quat_norm_variance: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x after the run (n,), F (k, n, n), Q (k, n, n)) for states x (n,) = [p v q (ba bw sa sw)] (m, m/s,
    Hamilton scalar-first C_b^n, m/s^2, rad/s, 1), n = 10 or 22, IMU samples us (k, 6) (m/s^2, rad/s, FRD)
    held over dts (k,) s, k >= 1. ``Q_base`` (k, n, n) float64, C-contiguous: each sample's
    attitude-independent noise, a new array of the caller's that is completed in place (its q block
    written) and returned as Q; ``var_w`` the gyro's white-noise variance density (rad^2/s),
    ``quat_norm_variance`` the variance along q. The compiled kernel when loaded, else
    :func:`linearise_run_numpy`."""
    if KERNEL is None:
        return linearise_run_numpy(x, us, dts, g, unit, Q_base, var_w, quat_norm_variance)
    n = x.shape[0]
    x1 = np.empty(n)
    F = np.empty((dts.shape[0], n, n))
    KERNEL.linearise(np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(us, dtype=float),
                     np.ascontiguousarray(dts, dtype=float), g, unit, var_w, quat_norm_variance, x1, F, Q_base)
    return x1, F, Q_base


def linearise_run_numpy(x: np.ndarray, us: np.ndarray, dts: np.ndarray, g: float, unit: bool,
                        Q_base: np.ndarray, var_w: float, quat_norm_variance: float
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`linearise_run` in numpy: the reference of the compiled kernel and the code that runs without it."""
    n = x.shape[0]
    k = dts.shape[0]
    if n == 22:
        us = (us - x[10:16]) / x[16:22]                            # eq. 11 solved for the true input
    a = us[:, :3]
    w = us[:, 3:]
    hh = (0.5 * dts)[:, None] * w                                  # half rotation vector (k, 3)
    s = np.sqrt((hh * hh).sum(axis=1))
    sin_s, cos_s = np.sin(s), np.cos(s)
    tiny = s <= 1e-300
    ss = np.where(tiny, 1.0, s)
    sinc = np.where(tiny, 1.0, sin_s / ss)
    small = s <= 1e-4
    c3 = np.where(small, -1.0 / 3.0 + s * s / 30.0, (ss * cos_s - sin_s) / ss ** 3)
    dq = np.empty((k, 4))
    dq[:, 0] = cos_s
    dq[:, 1:] = sinc[:, None] * hh                                 # eqs. 43-49
    qs = _chain(x[6:10].tolist(), dq, unit)
    q = qs[:-1]                                                     # attitude before each sample (k, 4)
    qq = q[:, :, None] * q[:, None, :]
    qq16 = qq.reshape(k, 16)
    d = qq16[:, ::5]                                                # q_i q_i
    n2 = d[:, 0] + d[:, 1] + d[:, 2] + d[:, 3]
    C = (qq16 @ _R_OF_QQ).reshape(k, 3, 3)                         # C_b^n = R(q) / |q|^2 (eq. 35)
    C /= n2[:, None, None]
    # numpy sums fewer than 8 terms left to right: the same numbers as C[.., 0] a0 + C[.., 1] a1 + C[.., 2] a2
    Ca = (C * a[:, None, :]).sum(axis=2)
    acc = Ca.copy()
    acc[:, 2] += g
    # v_{j+1} = v_j + (C a + g) dt, r_{j+1} = r_j + v_j dt: running sums in the order of the per-sample steps
    steps = np.empty((k + 1, 3))
    steps[0] = x[3:6]
    np.multiply(acc, dts[:, None], out=steps[1:])
    v = np.cumsum(steps, axis=0)
    steps[0] = x[0:3]
    np.multiply(v[:-1], dts[:, None], out=steps[1:])
    r = np.cumsum(steps, axis=0)
    x1 = x.copy()
    x1[0:3], x1[3:6], x1[6:10] = r[-1], v[-1], qs[-1]

    F = _identities(k, n)
    F.reshape(k, n * n)[:, [3, n + 4, 2 * n + 5]] = dts[:, None]      # F[0, 3], F[1, 4], F[2, 5]: dp/dv = I dt
    # d(C a)/dq for the normalised C: (dR/dq a - 2 C a q^T) / |q|^2, R the homogeneous form
    dRa = ((q[:, :, None] * a[:, None, :]).reshape(k, 12) @ _DRA_OF_QA).reshape(k, 3, 4)
    F[:, 3:6, 6:10] = (dts / n2)[:, None, None] * (dRa - 2.0 * Ca[:, :, None] * q[:, None, :])
    F[:, 6:10, 6:10] = (dq @ _RIGHT).reshape(k, 4, 4)                 # R(dq): q_new = R(dq) q
    if n == 22:
        # d dq / dw (4, 3), then d q_new / dw = L(q) d dq / dw
        D = np.empty((k, 4, 3))
        D[:, 0] = (-0.5 * sinc * dts)[:, None] * hh
        D[:, 1:] = (0.5 * c3 * dts)[:, None, None] * hh[:, :, None] * hh[:, None, :]
        D[:, 1:] += (0.5 * sinc * dts)[:, None, None] * _I3
        L = (q @ _LEFT).reshape(k, 4, 4)                             # L(q): q (x) p = L(q) p
        Ldw = L @ D
        inv_sa = 1.0 / x[16:19]
        inv_sw = 1.0 / x[19:22]
        Cm = C * -dts[:, None, None]
        F[:, 3:6, 10:13] = Cm * inv_sa                               # df/dba = -C / sa dt
        F[:, 3:6, 16:19] = Cm * (a * inv_sa)[:, None, :]             # df/dsa = -C a / sa dt
        F[:, 6:10, 13:16] = -Ldw * inv_sw
        F[:, 6:10, 19:22] = -Ldw * (w * inv_sw)[:, None, :]

    # the q block of Q: N_w^2 dt / 4 (|q|^2 I - q q^T) plus quat_norm_variance along q (ins_states._noise)
    Q = Q_base
    kw = var_w * dts / 4.0
    blk = qq * (quat_norm_variance / n2 - kw)[:, None, None]
    blk += (n2 * kw)[:, None, None] * _I4
    Q[:, 6:10, 6:10] = blk
    return x1, F, Q
