"""The paper-002 state sets of the ``ins`` process: 10 states ``[p v q]`` and 22 states ``[p v q ba bw sa sw]``
(paper 002 eqs. 8, 11-13), built by ``ins`` with ``states: 10`` or ``states: 22`` (``states: 16`` is
:class:`~fusion_plugins.process.ins.Ins` itself, unchanged).

Both drive the 16-state model (its propagation, analytic Jacobian, noise and run-of-samples kernels in
ins.py / ins_batch.py) with a corrected input instead of copying its maths:

* 22 states: the sensor model of eq. 11, ``u~ = s (.) u + b + w`` per axis (``s`` the scale factor,
  1 = nominal), so the true input is ``u = (u~ - b) / s`` and eq. 8 is the 16-state propagation with that
  input and zero biases. Biases and scale factors are random walks (eqs. 12-13). Chain rule for the
  Jacobian (``F16_b = d f16 / d b16`` at the corrected input, = -d f16 / du)::

      df/db = F16_b diag(1 / s),   df/ds = F16_b diag(u / s)

* 10 states: no sensor errors in the state; the 16-state model with zero biases, rows/columns 0-9.

Noise: the 16-state ``Q`` (white sensor noise and bias random walks) plus ``N_s^2 dt`` on the scale
factors. The white noise enters as ``w / s``; with ``|s - 1|`` of a few percent its variance is taken at
s = 1 (an error of ~2 |s - 1| in the variance, far inside the uncertainty of data-sheet densities).
"""
from __future__ import annotations

import copy
import math

import numpy as np

from fusion.api import BuildContext, Event, Message, StateLayout

from .ins import Ins, InsParams, density_variance
from .ins_params import InsProcess
from . import ins_linearise
from .ins_linearise import linearise_run

__all__ = ["InsStates"]

_LAYOUTS = {10: StateLayout.parse("p:3 v:3 q:4:quaternion"),
            22: StateLayout.parse("p:3 v:3 q:4:quaternion ba:3 bw:3 sa:3 sw:3")}


class InsStates(InsProcess):
    """Strapdown INS with the 10- or 22-state set of paper 002 (eqs. 8, 11-13), NED / FRD.

    State: ``p`` (m, NED), ``v`` (m/s, NED), ``q`` (Hamilton, scalar first, C_b^n); with 22 states also
    ``ba`` (m/s^2), ``bw`` (rad/s) biases and ``sa``, ``sw`` scale factors (1 = nominal), FRD, per axis.
    Input ``u = [ax ay az gx gy gz]`` (m/s^2, rad/s, FRD). The integration, eta, gravity, Earth rate and
    the input checks are those of ``ins`` (same parameters); see the module docstring for the mapping.
    """


    def __init__(self, params: InsParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        p: InsParams = self.params  # type: ignore[assignment]
        if p.states not in _LAYOUTS:
            raise ValueError(f"InsStates builds states 10 or 22, got {p.states}")
        self.states = p.states
        self.layout = _LAYOUTS[p.states] if p.renormalize else _LAYOUTS[p.states].with_unit(False)
        self.core = Ins(p.model_copy(update={"states": 16, "accel_scale_rw": 0.0, "gyro_scale_rw": 0.0}), context)
        self.g, self.g_n = self.core.g, self.core.g_n
        self._var_s = np.concatenate([density_variance(p.accel_scale_rw), density_variance(p.gyro_scale_rw)])
        # Fast path for one point (the EKF): the paper's Euler step without eta, Earth rate or anisotropic
        # noise, in scalar arithmetic with f, F and Q computed once per (x, u, dt) (the EKF asks for all
        # three). The same numbers as the general path to rounding (tests/models/test_ins_states.py).
        c = self.core
        self._fast = (p.integration == "euler" and p.eta == 0.0 and c.w_ie is None
                      and c._qc_diag is not None)
        self._hold = p.hold_after if p.hold_after is not None else math.inf   # a longer step: general path
        self.hold_after = p.hold_after        # fusion.api.HoldsInput
        self._cache_key: tuple | None = None
        self._cache: tuple = ()
        self._Qc: dict[float, np.ndarray] = {}
        self._base_coef: tuple | None = None

    def held(self, age: float) -> "InsStates":
        """fusion.api.HoldsInput: this model for a prediction that starts ``age`` s after the sample it
        holds (the 16-state core's :meth:`Ins.held`; the fast path only within what is left of hold_after)."""
        if self.hold_after is None or age <= 0.0:
            return self
        c = copy.copy(self)
        c.core = self.core.held(age)
        c._hold = max(0.0, self._hold - age)
        return c

    # ------------------------------------------------------------------ mapping to the 16-state model
    def _core(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x16 with zero biases, corrected input) for states x (..., n) and raw input u (6,) or (..., 6)."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        x16 = np.zeros(x.shape[:-1] + (16,))
        x16[..., :10] = x[..., :10]
        if self.states == 10:
            return x16, u
        return x16, (u - x[..., 10:16]) / x[..., 16:22]          # eq. 11 solved for the true input

    def f(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """Propagate states x (..., n) over dt (s) with the IMU sample u (6,): eq. 8 (+ eqs. 12-13)."""
        if u is None:
            raise ValueError("process 'ins' needs the IMU sample u = [ax ay az gx gy gz]")
        if self._fast and dt <= self._hold and np.ndim(x) == 1 and np.ndim(u) == 1:
            return self._step(x, u, dt)[0].copy()
        x16, ue = self._core(x, u)
        y = self.core.f(x16, ue, dt)
        out = np.array(np.broadcast_to(x, y.shape[:-1] + (self.layout.n,)), dtype=float)
        out[..., :10] = y[..., :10]                              # biases and scale factors: mean kept
        return out

    def f_inputs(self, x: np.ndarray, us: np.ndarray, dts: np.ndarray) -> np.ndarray:
        """States after the run of samples ``us`` (k, 6) held over ``dts`` (k,): the same as k calls of
        :meth:`f` (10 states: the 16-state vectorised kernel; 22: sample by sample, since the corrected
        input differs between sigma points)."""
        us = np.asarray(us, dtype=float)
        dts = np.asarray(dts, dtype=float)
        if self.states == 10:
            x16, _ = self._core(x, us[0])
            return self.core.f_inputs(x16, us, dts)[..., :10]
        for u, dt in zip(us, dts):
            x = self.f(x, u, float(dt))
        return x

    def input_from(self, message: Message) -> np.ndarray:
        return self.core.input_from(message)

    def step_events(self, t: float, dts: np.ndarray) -> tuple[Event, ...]:
        """The 16-state model's events of a step (``eta_clamped``: the same eta, the same rule)."""
        return self.core.step_events(t, dts)

    # ------------------------------------------------------------------ linearisation and noise
    def jacobian(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """Analytic F = df/dx (n, n) at x (n,), from the 16-state F by the chain rule (module docstring)."""
        if u is None:
            raise ValueError("process 'ins' needs the IMU sample u = [ax ay az gx gy gz]")
        if self._fast and dt <= self._hold:
            return self._step(x, u, dt)[1].copy()
        x = np.asarray(x, dtype=float)
        x16, ue = self._core(x, u)
        F16 = self.core.jacobian(x16, ue, dt)
        F = np.eye(self.layout.n)
        F[:10, :10] = F16[:10, :10]
        if self.states == 22:
            Fb = F16[:10, 10:16]
            s = x[16:22]
            F[:10, 10:16] = Fb / s
            F[:10, 16:22] = Fb * (ue / s)
        return F

    def _embed(self, Q16: np.ndarray, dt_total: float) -> np.ndarray:
        if self.states == 10:
            return Q16[:10, :10].copy()
        Q = np.zeros((22, 22))
        Q[:16, :16] = Q16
        Q[16:, 16:] = np.diag(self._var_s * dt_total)          # eq. 13: scale-factor random walks
        return Q

    def Q(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """Discrete process noise (n, n) over dt: the 16-state Q (ins.py) plus the scale random walks."""
        if self._fast and dt <= self._hold and np.ndim(x) == 1:
            return self._noise(np.asarray(x, dtype=float), dt)
        x16, ue = self._core(x, u if u is not None else np.zeros(6))
        return self._embed(self.core.Q(x16, ue, dt), dt)

    def Q_inputs(self, x0: np.ndarray, x1: np.ndarray, us: np.ndarray, dts: np.ndarray) -> np.ndarray:
        """Process noise (n, n) of a run of samples (the 16-state interval noise, ins_batch.interval_noise)."""
        a = np.zeros(16)
        b = np.zeros(16)
        a[:10], b[:10] = np.asarray(x0, float)[:10], np.asarray(x1, float)[:10]
        return self._embed(self.core.Q_inputs(a, b, us, dts), float(np.sum(dts)))

    def linearise_inputs(self, x: np.ndarray, us: np.ndarray, dts: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The EKF's run of samples (capability LinearisesInputRuns): the normalised mean after ``us``
        (k, 6) held over ``dts`` (k,) s, and each sample's F and Q (k, n, n) at the mean before it, in one
        vectorised pass (ins_linearise.py), or in one call of its compiled kernel (_ins_run_kernel.c) when
        built; the fast path's conditions only, else None."""
        if not self._fast or np.ndim(x) != 1:
            return None
        dts = np.asarray(dts, dtype=float)
        dl = dts.tolist()
        # plain floats: cheaper than a numpy reduction (the run has ~10 samples)
        if not dl or max(dl) > self._hold or min(dl) <= 0.0:
            return None
        kernel = ins_linearise.KERNEL
        if kernel is not None:       # linearise_run and _q_base_run in one C call (_ins_run_kernel.c)
            n, k = self.layout.n, len(dl)
            x1, F, Q = np.empty(n), np.empty((k, n, n)), np.empty((k, n, n))
            kernel.linearise(np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(us, dtype=float),
                             np.ascontiguousarray(dts), self.g, bool(self.layout.unit_quaternions),
                             float(self.core._var_w[0]), self.params.quat_norm_variance,  # type: ignore[attr-defined]
                             x1, F, Q, *self._noise_coefficients())
            return x1, F, Q
        return linearise_run(np.asarray(x, dtype=float), np.asarray(us, dtype=float), dts, self.g,
                             bool(self.layout.unit_quaternions), self._q_base_run(dts), float(self.core._var_w[0]),
                             self.params.quat_norm_variance)  # type: ignore[attr-defined]

    def _q_base_run(self, dts: np.ndarray) -> np.ndarray:
        """:meth:`_q_base` of every sample of a run at once, (k, n, n), a new array (the caller fills the q
        block). The blocks are elementwise in dt (``Q1 dt + Q2 dt^2 + Q3 dt^3``, ins.py's ``Q``, and the
        scale-factor walks ``N_s^2 dt``), so evaluating them over the run gives the same numbers as
        :meth:`_q_base` per sample; a cache per dt would miss: the intervals of a recording differ in
        their last bits (0.01999999999999602, 0.020000000000003126, ...)."""
        k, n = dts.shape[0], self.layout.n
        c1, c2, c3 = self._noise_coefficients()
        kernel = ins_linearise.KERNEL
        if kernel is not None:                        # the same sums in C (_ins_run_kernel.c noise_base)
            Q = np.empty((k, n, n))
            kernel.noise_base(np.ascontiguousarray(dts, dtype=float), c1, c2, c3, Q)
            return Q
        d2 = dts * dts
        # zero coefficients give exact zeros, so the sums are those of the nonzero terms, in Q's order
        Q = np.multiply.outer(dts, c1)
        Q += np.multiply.outer(d2, c2)
        Q += np.multiply.outer(d2 * dts, c3)
        return Q.reshape(k, n, n)                                 # the q block: linearise_run's

    def _noise_coefficients(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(c1, c2, c3), each (n*n,): the attitude-independent Q over dt is ``c1 dt + c2 dt^2 + c3 dt^3``
        (ins.py's Q1, Q2, Q3 with the scale walks' N_s^2 in c1), computed once."""
        if self._base_coef is None:
            n = self.layout.n
            if n == 10:
                Q1, Q2, Q3 = (np.ascontiguousarray(c[:10, :10]) for c in self.core._Qdt)
            else:
                Q1, Q2, Q3 = (np.pad(c, (0, 6)) for c in self.core._Qdt)
                Q1[16:, 16:] = np.diag(self._var_s)                   # eq. 13: scale-factor random walks
            self._base_coef = tuple(c.reshape(n * n) for c in (Q1, Q2, Q3))
        return self._base_coef  # type: ignore[return-value]

    # ------------------------------------------------------------------ the one-point fast path
    def _step(self, x: np.ndarray, u: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(f, F) of one state x (n,) for the Euler step (eq. 8 with ``p += v dt``, ins.py's ``euler``),
        scalar arithmetic; cached for the last (x, u, dt)."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        key = (x.tobytes(), u.tobytes(), dt)
        if key == self._cache_key:
            return self._cache
        n = self.layout.n
        xl = x.tolist()
        ul = u.tolist()
        if n == 22:
            a = [(ul[i] - xl[10 + i]) / xl[16 + i] for i in range(3)]      # eq. 11 solved for the input
            w = [(ul[3 + i] - xl[13 + i]) / xl[19 + i] for i in range(3)]
        else:
            a, w = ul[:3], ul[3:]
        q0, q1, q2, q3 = xl[6:10]
        n2 = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3
        # C_b^n from q / |q| (paper 000 eq. 35 / |q|^2)
        C = [[(q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3) / n2, 2 * (q1 * q2 - q0 * q3) / n2, 2 * (q1 * q3 + q0 * q2) / n2],
             [2 * (q1 * q2 + q0 * q3) / n2, (q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3) / n2, 2 * (q2 * q3 - q0 * q1) / n2],
             [2 * (q1 * q3 - q0 * q2) / n2, 2 * (q2 * q3 + q0 * q1) / n2, (q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3) / n2]]
        Ca = [C[r][0] * a[0] + C[r][1] * a[1] + C[r][2] * a[2] for r in range(3)]
        h = [0.5 * dt * wi for wi in w]
        s = math.sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2])
        sinc = math.sin(s) / s if s > 1e-300 else 1.0
        c3 = (s * math.cos(s) - math.sin(s)) / s ** 3 if s > 1e-4 else -1.0 / 3.0 + s * s / 30.0
        p0, p1, p2, p3 = math.cos(s), sinc * h[0], sinc * h[1], sinc * h[2]        # dq, eqs. 43-49
        y = x.copy()
        g = self.g
        for i in range(3):
            y[i] = xl[i] + xl[3 + i] * dt                                       # r += v dt
            y[3 + i] = xl[3 + i] + (Ca[i] + (g if i == 2 else 0.0)) * dt        # v += (C f + g) dt
        y[6] = q0 * p0 - q1 * p1 - q2 * p2 - q3 * p3                           # q (x) dq
        y[7] = q0 * p1 + q1 * p0 + q2 * p3 - q3 * p2
        y[8] = q0 * p2 - q1 * p3 + q2 * p0 + q3 * p1
        y[9] = q0 * p3 + q1 * p2 - q2 * p1 + q3 * p0
        F = np.eye(n)
        F[0, 3] = F[1, 4] = F[2, 5] = dt
        # d(C a)/dq for the normalised C: (dR/dq a - 2 C a q^T) / |q|^2, R the homogeneous form
        va = q1 * a[0] + q2 * a[1] + q3 * a[2]
        qxa = [q2 * a[2] - q3 * a[1], q3 * a[0] - q1 * a[2], q1 * a[1] - q2 * a[0]]
        qv = (q1, q2, q3)
        ax_ = [[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]]
        qq = (q0, q1, q2, q3)
        for r in range(3):
            dR = [2 * (q0 * a[r] + qxa[r])] + [2 * ((va if r == k else 0.0) + qv[r] * a[k] - a[r] * qv[k] - q0 * ax_[r][k])
                                              for k in range(3)]
            for k in range(4):
                F[3 + r, 6 + k] = dt * (dR[k] - 2.0 * Ca[r] * qq[k]) / n2
        F[6:10, 6:10] = ((p0, -p1, -p2, -p3), (p1, p0, p3, -p2), (p2, -p3, p0, p1), (p3, p2, -p1, p0))   # R(dq)
        if n == 22:
            # d dq / dw (4, 3), then d q_new / dw = L(q) d dq / dw
            D = np.empty((4, 3))
            D[0] = [-0.5 * sinc * hi * dt for hi in h]
            for r in range(3):
                D[1 + r] = [(0.5 * sinc * (1.0 if r == k else 0.0) + 0.5 * c3 * h[r] * h[k]) * dt for k in range(3)]
            L = np.array(((q0, -q1, -q2, -q3), (q1, q0, -q3, q2), (q2, q3, q0, -q1), (q3, -q2, q1, q0)))
            Ldw = L @ D
            inv_sa = 1.0 / x[16:19]
            inv_sw = 1.0 / x[19:22]
            Cm = np.array(C) * -dt
            F[3:6, 10:13] = Cm * inv_sa                                          # df/dba = -C / sa dt
            F[3:6, 16:19] = Cm * (np.array(a) * inv_sa)                          # df/dsa = -C a / sa dt
            F[6:10, 13:16] = -Ldw * inv_sw
            F[6:10, 19:22] = -Ldw * (np.array(w) * inv_sw)
        self._cache_key, self._cache = key, (y, F)
        return y, F

    def _q_base(self, dt: float) -> np.ndarray:
        """The attitude-independent blocks of the fast path's Q over dt (q block zero), cached per dt."""
        base = self._Qc.get(dt)
        if base is None:
            base = self._embed(self.core.Q(np.r_[np.zeros(6), 1.0, np.zeros(9)], None, dt), dt)
            base[6:10, 6:10] = 0.0
            if len(self._Qc) > 8:
                self._Qc.clear()
            self._Qc[dt] = base
        return base

    def _noise(self, x: np.ndarray, dt: float) -> np.ndarray:
        """Q (n, n) of the fast path: the attitude-independent blocks cached per dt, the q block
        ``N_w^2 dt / 4 (|q|^2 I - q q^T)`` plus ``quat_norm_variance`` along q (as ins.py's Q)."""
        Qm = self._q_base(dt).copy()
        q = x[6:10]
        n2 = float(q @ q)
        kw = self.core._var_w[0] * dt / 4.0
        blk = q[:, None] * q
        blk *= self.params.quat_norm_variance / n2 - kw  # type: ignore[attr-defined]
        blk.flat[::5] += n2 * kw
        Qm[6:10, 6:10] = blk
        return Qm

    # ------------------------------------------------------------------ initial alignment
    def stillness(self, x0: np.ndarray, P0: np.ndarray, us: np.ndarray, ts: np.ndarray) -> tuple[bool, str] | None:
        """``Ins.stillness`` of the window's raw IMU samples (the spread, which scale factors hardly change)."""
        x16 = np.zeros(16)
        x16[:min(16, len(x0))] = np.asarray(x0, dtype=float)[:16]
        return self.core.stillness(x16, np.eye(16), us, ts)

    def align(self, x0: np.ndarray, P0: np.ndarray, u_mean: np.ndarray, still: bool = True,
              window: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Levelling from the mean static IMU sample (``Ins.align``): roll and pitch from gravity corrected
        by the initial bias and scale factor, yaw kept; with 22 states and ``align_gyro_bias`` the gyro bias
        becomes the mean static rate (a static gyro reads b, whatever its scale). ``still``, ``window``: as
        ``Ins.align`` (a moving window keeps the bias prior, its rotation carries the yaw)."""
        x0 = np.array(x0, dtype=float, copy=True)
        u = np.array(u_mean, dtype=float, copy=True)
        x16 = np.zeros(16)
        x16[:10] = x0[:10]
        if self.states == 22:
            ba, sa = x0[10:13], x0[16:19]
            x16[10:16] = x0[10:16]
            u[:3] = ba + (u[:3] - ba) / sa                       # so that u - ba = (u~ - ba) / sa
        y, _ = self.core.align(x16, np.eye(16), u, still=still, window=window)
        x0[:10] = y[:10]
        if self.states == 22:
            x0[10:16] = y[10:16]
        return x0, np.array(P0, dtype=float, copy=True)
