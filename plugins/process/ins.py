"""Process ``ins``: IMU-driven 16-state strapdown INS (paper 000, sec. V-A, eqs. 33-52)."""
from __future__ import annotations

import copy
import math
from typing import ClassVar

import numpy as np

from fusion import kernels
from fusion import quaternion as quat
from fusion.api import (BuildContext, Event, MalformedMessage, Message, Params, ProcessModel,  # noqa: F401
                        RejectedMessage, StateLayout)

from .ins_batch import K10T as _K10T, T16T as _T16T, integrate_inputs
from .ins_noise import InsNoise
from .ins_params import (ADIS16364_ACCEL_BIAS_RW, ADIS16364_ACCEL_ND, ADIS16364_GYRO_BIAS_RW, ADIS16364_GYRO_ND,  # noqa: F401
                         EARTH_RATE, STANDARD_GRAVITY, Density, InsParams, density_variance, somigliana_gravity)

_KERNEL = kernels.load("fusion_plugins.process._ins_batch_kernel")   # input_from's checks (imu_ok)

#: The alignment's stillness test (Ins.stillness): significance of each test, and the factor on the noise
#: density's sd that a window's spread must exceed. Data-sheet densities are typical values: a static unit on
#: a standing vehicle (fans, an idling engine) reads up to a few times them, a driven one tens of times
#: (tester5 #5: 10x on the gyro z and the accelerometer x of a vehicle driving a bend), so 3x is "clearly
#: not static", not "noisier than the sheet".
STILL_ALPHA = 1e-6
STILL_SD_FACTOR = 3.0


def coast(x: np.ndarray, e: float) -> np.ndarray:
    """States x (..., n) (``p v`` first, m, m/s) after e s without an IMU sample: attitude, velocity and
    sensor states kept, ``p += v e`` (a new array). Past ``hold_after`` the held sample is no estimate of
    the input any more (a turn's rate held for seconds turns the estimate through tens of degrees): the
    mean coasts and the hold noise (ins_batch.add_hold_noise) carries what the vehicle may have done."""
    y = np.array(x, dtype=float, copy=True)
    y[..., 0:3] += e * y[..., 3:6]
    return y


class Ins(InsNoise, ProcessModel):
    """Strapdown INS driven by the IMU (paper 000 eqs. 33-52), NED navigation frame, FRD body frame.

    State (eq. 33), 16 elements: ``p`` position (m, NED), ``v`` velocity (m/s, NED), ``q`` attitude
    (Hamilton, scalar first, body-to-navigation C_b^n), ``ba`` accelerometer bias (m/s^2, FRD),
    ``bw`` gyro bias (rad/s, FRD). Input ``u = [ax ay az gx gy gz]``: the IMU's specific force (m/s^2)
    and angular rate (rad/s), FRD body frame.

    Propagation over dt (one IMU sample, held constant over the interval):

    .. math::
        a = \\tilde a - b_a,\\quad \\omega = \\tilde\\omega - b_\\omega - C_n^b \\omega_{ie}^n
        \\quad (37, 38;\\ \\omega_{ie}^n = \\Omega_e[\\cos\\varphi, 0, -\\sin\\varphi] \\text{ if earth\\_rate})

        p_{k+1} = p_k + v_k dt, \\quad v_{k+1} = v_k + (C_b^n(q_k) a + g_n) dt \\quad (40, 41; g_n = [0, 0, g])

        q_{k+1} = [I(\\cos s + \\eta\\,dt\\,\\lambda) - \\tfrac12 \\Phi_\\Delta \\tfrac{\\sin s}{s}] q_k,
        \\quad s = \\tfrac12|\\omega| dt,\\ \\lambda = 1 - |q_k|^2 \\quad (43-50)

        b_{a,k+1} = b_{a,k},\\quad b_{\\omega,k+1} = b_{\\omega,k} \\quad (51, 52: random walks, zero-mean steps)

    Eq. 50 is evaluated as ``q_k (x) [cos s + eta dt lambda, (sin s / s) w dt / 2]``, the same matrix
    (``-Phi/2`` is right multiplication by ``[0, w dt/2]``, eq. 39 corrected). The Euler updates of p and
    v are the paper's; ``integration: trapezoidal`` uses ``a_n = (C_k + C_{k+1}) a / 2 + g_n``,
    ``v += a_n dt``, ``p += v dt + a_n dt^2 / 2`` instead. C_b^n is computed from q / |q| (eq. 35
    divided by |q|^2) so non-unit sigma points still rotate rigidly. The Coriolis and transport-rate
    terms of the velocity equation are neglected, as in eq. 34 (2 w_ie v < 2e-4 m/s^2 at mine speeds).

    Norm correction (eq. 50): the step scales |q| by about ``1 + eta dt (1 - |q|^2)``, which converges
    for ``eta dt < 1`` (paper's condition); when a step has ``eta dt >= 1`` (a long gap) the product is
    clamped to 0.5 (dead-beat) and reported by :meth:`step_events` (an ``eta_clamped`` event per such sample,
    counted by the run in ``summary["filter_counters"]``).

    Noise ``Q(x, u, dt)``, from continuous white-noise densities N (YAML): accelerometer N_a enters v
    as in the integrated double integrator (Q_vv = C N_a^2 C^T dt, Q_pv = Q_vv dt/2, Q_pp = Q_vv dt^2/3);
    gyro N_w enters q through ``dq/dw = Xi(q) dt/2`` (first order): Q_qq = (dt/4) Xi(q) N_w^2 Xi(q)^T
    (rank 3: nothing along q itself, plus ``quat_norm_variance`` q q^T/|q|^2 if set); biases
    Q_ba = N_ba^2 dt, Q_bw = N_bw^2 dt (eqs. 51-52 with W of variance N^2/dt). Cross terms between the
    bias random walks and v, q are second order in dt and neglected. A sample held past ``hold_after``
    (an IMU gap) is integrated over ``hold_after`` only, then the state coasts (:func:`coast`), and the
    hold noise covers the excess time (``ins_batch.add_hold_noise``).

    A run of samples in one step (the filters' ``predict_inputs``): :meth:`f_inputs` (exact, vectorised
    over the samples) and :meth:`Q_inputs` (the noise of the interval through the error dynamics).

    ``states: 10`` (``[p v q]``) or ``states: 22`` (plus accelerometer and gyro scale factors ``sa``,
    ``sw``, random walks ``accel_scale_rw``, ``gyro_scale_rw``: paper 002 eqs. 8, 11-13) build
    ``ins_states.InsStates``, which drives this model with the corrected input ``(u - b) / s``.
    """

    name: ClassVar[str] = "ins"
    Params: ClassVar[type[Params]] = InsParams
    layout: StateLayout = StateLayout.parse("p:3 v:3 q:4:quaternion ba:3 bw:3")
    input_dim: int = 6
    input_fields = ("ax", "ay", "az", "gx", "gy", "gz")   # m/s^2, rad/s, FRD body frame (a '# fields' line is checked against it)
    linear: bool = False

    def __new__(cls, params: InsParams | None = None, context: BuildContext | None = None):
        """``states: 10`` or ``22`` build the paper-002 state sets (ins_states.InsStates, which drives this
        16-state model underneath); ``gauss_markov`` blocks build ins_gauss_markov.InsGaussMarkov (any of
        those with the blocks appended); 16 without blocks is this class as it is."""
        if cls is Ins and params is not None and getattr(params, "gauss_markov", None):
            from .ins_gauss_markov import InsGaussMarkov
            return InsGaussMarkov(params, context)
        if cls is Ins and params is not None and getattr(params, "states", 16) != 16:
            from .ins_states import InsStates
            return InsStates(params, context)
        return super().__new__(cls)

    def __init__(self, params: InsParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        p: InsParams = self.params  # type: ignore[assignment]
        if not p.renormalize:   # the filters leave |q| to eta or a quat_norm pseudo-observation
            self.layout = type(self).layout.with_unit(False)
        if p.gravity is not None:
            g = p.gravity
        elif p.latitude_deg is not None:
            g = somigliana_gravity(p.latitude_deg, p.height_m)
        else:
            g = float(self.context.extra.get("gravity", STANDARD_GRAVITY))
        self.g: float = g
        self.g_n: np.ndarray = np.array([0.0, 0.0, g])
        if p.earth_rate:
            lat = np.radians(p.latitude_deg)  # type: ignore[arg-type]
            self.w_ie: np.ndarray | None = EARTH_RATE * np.array([np.cos(lat), 0.0, -np.sin(lat)])
        else:
            self.w_ie = None
        self._var_a, self._var_w = density_variance(p.accel_noise_density), density_variance(p.gyro_noise_density)
        self._var_ba, self._var_bw = density_variance(p.accel_bias_rw), density_variance(p.gyro_bias_rw)
        self._trap = p.integration == "trapezoidal"
        self._g_col = self.g_n[:, None]
        # Q's attitude-independent blocks per power of dt (accelerometer noise isotropic: C N^2 C^T = N^2 I)
        Q1 = np.zeros((16, 16))
        Q1[10:13, 10:13] = np.diag(self._var_ba)
        Q1[13:16, 13:16] = np.diag(self._var_bw)
        if np.ptp(self._var_a) == 0.0:
            Q2, Q3, na = np.zeros((16, 16)), np.zeros((16, 16)), self._var_a[0] * np.eye(3)
            Q1[3:6, 3:6] = na
            Q2[0:3, 3:6] = Q2[3:6, 0:3] = na / 2.0
            Q3[0:3, 0:3] = na / 3.0
            self._Qdt: tuple = (Q1, Q2, Q3)
        else:
            self._Qdt = (Q1, None, None)
        self._iso_w = bool(np.ptp(self._var_w) == 0.0)
        self._qc_diag = (np.concatenate([np.zeros(3), self._var_a, self._var_w, self._var_ba, self._var_bw])
                         if self._iso_w and np.ptp(self._var_a) == 0.0 else None)
        # Nothing is counted inside the model: clamps are step_events, counted by the run.
        self._max_f, self._max_w = p.max_specific_force, p.max_rate
        self._lim_f, self._lim_w = (math.inf if v is None else float(v) for v in (self._max_f, self._max_w))
        self._hold = p.hold_after
        self.hold_after = p.hold_after        # fusion.api.HoldsInput (``_hold`` is what is left of it: held())
        self._excess0 = 0.0                   # s the held sample is already past hold_after (held())

    def held(self, age: float) -> "Ins":
        """fusion.api.HoldsInput: this model for a prediction that starts ``age`` s after the sample it
        holds: the sample is integrated over what is left of ``hold_after`` (none once it has passed),
        then the state coasts with the hold noise. A shallow copy (the caches are shared: a held step
        within what is left of ``hold_after`` is an ordinary step)."""
        if self._hold is None or age <= 0.0:
            return self
        c = copy.copy(self)
        c._hold = max(0.0, self._hold - age)
        c._excess0 = max(0.0, age - self._hold)
        return c

    # ------------------------------------------------------------------ propagation
    def _eta_dt(self, dt: float) -> float:
        e = self.params.eta * dt  # type: ignore[attr-defined]
        return 0.5 if e >= 1.0 else e

    def step_events(self, t: float, dts: np.ndarray) -> tuple[Event, ...]:
        """fusion.api.ReportsStepEvents: one ``eta_clamped`` event per sample of the step with eta dt >= 1
        (the gain clamped to 0.5: a gap in the IMU samples), none otherwise. A pure function of
        the intervals ``dts`` (s): the run counts the events (``summary["filter_counters"]``)."""
        eta = self.params.eta  # type: ignore[attr-defined]
        if not eta:
            return ()
        n = int(np.count_nonzero(np.asarray(dts, dtype=float) * eta >= 1.0))
        if not n:
            return ()
        e = Event(float(t), "eta_clamped", None, f"IMU interval with eta dt >= 1 (eta {eta:g} /s): the "
                  "norm-correction gain of eq. 50 clamped to 0.5")
        return (e,) * n

    def f(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """Propagate states x (..., 16) over dt (s) with the IMU sample u (6,) or (..., 6); see the class doc.
        A sample held longer than ``hold_after`` (an IMU gap) is integrated over ``hold_after`` only, then
        the state coasts (:func:`coast`: attitude and velocity kept, p += v e over the excess e).

        Evaluated once on the whole sigma-point array, stored component-first ((16, N)), so each line is
        one numpy call on whole rows: no loop over points, no stacked 4x4 products."""
        if u is None:
            raise ValueError("process 'ins' needs the IMU sample u = [ax ay az gx gy gz]")
        h = self._hold
        if h is not None and dt > h:
            return coast(self._f(x, u, h) if h > 0.0 else x, dt - h)
        return self._f(x, u, dt)

    def _f(self, x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        """:meth:`f` without the hold: the sample integrated over the whole dt."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        lead = x.shape[:-1]
        if u.ndim > 1:
            lead = np.broadcast_shapes(lead, u.shape[:-1])
            x = np.broadcast_to(x, lead + (16,))
            U = np.broadcast_to(u, lead + (6,)).reshape(-1, 6).T
        else:
            U = u[:, None]
        X = x.reshape(-1, 16).T                                  # (16, N), a view
        N = X.shape[1]
        aw = U - X[10:16]                                        # eqs. 37-38 (noise-free mean): [a, w]
        q = X[6:10]
        Rn = _K10T @ (q[:, None] * q[None, :]).reshape(16, N)    # [R(q) (9 rows), |q|^2]
        n2 = Rn[9]
        C = (Rn[:9] / n2).reshape(3, 3, N)                       # C_b^n, eq. 35
        w = aw[3:]
        if self.w_ie is not None:
            w = w - (C * self.w_ie[:, None, None]).sum(axis=0)  # eq. 38: C_n^b w_ie^n
        half = w * (0.5 * dt)                                    # [dphi dtheta dpsi] / 2, eqs. 43-45
        s = np.sqrt((half * half).sum(axis=0))                   # eq. 49
        s_ = np.maximum(s, 1e-300)
        dq = np.empty((4, N))
        dq[0] = np.cos(s)
        eta_dt = self._eta_dt(dt)
        if eta_dt:
            dq[0] += eta_dt * (1.0 - n2)                         # eq. 50, lambda = 1 - |q|^2
        np.multiply(np.sin(s_) / s_, half, out=dq[1:])
        out = np.empty((16, N))
        q_new = out[6:10]
        np.matmul(_T16T, (q[:, None] * dq[None, :]).reshape(16, N), out=q_new)   # q (x) dq
        a = aw[:3]
        f_n = (C * a).sum(axis=1)                                # C_b^n a
        p, v = X[0:3], X[3:6]
        if self._trap:
            Rn = _K10T @ (q_new[:, None] * q_new[None, :]).reshape(16, N)
            f_n += ((Rn[:9] / Rn[9]).reshape(3, 3, N) * a).sum(axis=1)
            acc = 0.5 * f_n + self._g_col
            out[0:3] = p + (v + acc * (0.5 * dt)) * dt
        else:
            acc = f_n + self._g_col                              # eq. 34, v_dot
            out[0:3] = p + v * dt                                # eq. 40
        out[3:6] = v + acc * dt                                  # eq. 41
        out[10:16] = X[10:16]                                    # eqs. 51-52: mean bias kept
        return out.T.reshape(lead + (16,))

    def f_inputs(self, x: np.ndarray, us: np.ndarray, dts: np.ndarray) -> np.ndarray:
        """States x (..., 16) after the IMU samples ``us`` (k, 6), each held over its ``dts`` (k,) (s), in
        order: the same numbers as k calls of :meth:`f` (to rounding, ~1e-15), for the filters'
        ``predict_inputs`` (a run of samples between two measurements in one sigma-point step).

        Vectorised over the samples as well as the points by the compiled kernel (``ins_batch.integrate_inputs``:
        within a run the biases are constant and the rotation increments do not depend on the attitude). With
        eta > 0 (|q| enters every step), the Earth rate (it depends on the attitude), a sample held past
        ``hold_after`` (an IMU gap: the coast is not a sample), or without the kernel: k calls of :meth:`f`."""
        us = np.asarray(us, dtype=float)
        dts = np.asarray(dts, dtype=float)
        x = np.asarray(x, dtype=float)
        held = self._hold is not None and float(dts.max()) > self._hold
        if not (dts.shape[0] == 1 or self.params.eta or self.w_ie is not None or held):  # type: ignore[attr-defined]
            out = integrate_inputs(x, us, dts, self._g_col, self._trap)
            if out is not None:
                return out
        for u, dt in zip(us, dts):
            x = self.f(x, u, dt)
        return x

    def normalize(self, x: np.ndarray) -> np.ndarray:
        """Renormalise the quaternion block of states x (..., 16) to unit norm (a new array); with
        ``renormalize: false``, x itself (the norm is left to eta or the quat_norm pseudo-observation)."""
        return self.layout.normalize(x)   # renormalize: false -> a layout whose q block is not unit

    # ------------------------------------------------------------------ linearisation
    def _dq_dw(self, w: np.ndarray, dt: float) -> np.ndarray:
        """d[cos s, sinc(s) w dt/2] / dw (4, 3)."""
        half = 0.5 * dt * w
        s = float(np.linalg.norm(half))
        sinc = np.sinc(s / np.pi)
        # (s cos s - sin s) / s^3, with its series near 0
        c3 = (s * np.cos(s) - np.sin(s)) / s**3 if s > 1e-4 else -1.0 / 3.0 + s * s / 30.0
        d = np.empty((4, 3))
        d[0] = -0.5 * sinc * half
        d[1:] = 0.5 * sinc * np.eye(3) + 0.5 * c3 * np.outer(half, half)
        return d * dt

    def jacobian(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """Analytic F = df/dx (16, 16) at x (16,) (for the EKF), consistent with f including eq. 50 and the
        coast past ``hold_after``."""
        if u is None:
            raise ValueError("process 'ins' needs the IMU sample u = [ax ay az gx gy gz]")
        h = self._hold
        if h is not None and dt > h:
            F = self._jacobian(x, u, h) if h > 0.0 else np.eye(16)
            F[0:3] += (dt - h) * F[3:6]                          # coast: p += v e
            return F
        return self._jacobian(x, u, dt)

    def _jacobian(self, x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        """:meth:`jacobian` without the hold."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        q = x[6:10]
        a = u[:3] - x[10:13]
        w = u[3:] - x[13:16]
        n2 = q @ q
        C = quat.to_matrix(q)
        dw_dq = np.zeros((3, 4))
        if self.w_ie is not None:
            w = w - C.T @ self.w_ie
            # C^T w_ie = C(q*) w_ie, q* = diag(1,-1,-1,-1) q
            dw_dq = -quat.rotate_jacobian(quat.conjugate(q), self.w_ie) * np.array([1.0, -1.0, -1.0, -1.0])
        eta_dt = self.params.eta * dt  # type: ignore[attr-defined]
        eta_dt = 0.5 if eta_dt >= 1.0 else eta_dt
        half = 0.5 * dt * w
        s = np.linalg.norm(half)
        dq = np.concatenate([[np.cos(s) + eta_dt * (1.0 - n2)], np.sinc(s / np.pi) * half])
        L = quat.left_matrix(q)
        Ldw = L @ self._dq_dw(w, dt)                             # d q_new / d w (4, 3)
        F = np.eye(16)
        F[0:3, 3:6] = dt * np.eye(3)
        F_qq = quat.right_matrix(dq) - 2.0 * eta_dt * np.outer(q, q) + Ldw @ dw_dq
        F_qbw = -Ldw
        F[6:10, 6:10] = F_qq
        F[6:10, 13:16] = F_qbw
        # d f_n / d(q, ba, bw), f_n the navigation-frame specific force used over the step
        Jq = quat.rotate_jacobian(q, a)
        if self._trap:
            q_new = L @ dq
            Jq_new = quat.rotate_jacobian(q_new, a)
            dfn_dq = 0.5 * (Jq + Jq_new @ F_qq)
            dfn_dba = -0.5 * (C + quat.to_matrix(q_new))
            dfn_dbw = 0.5 * Jq_new @ F_qbw
            kp = 0.5 * dt * dt
        else:
            dfn_dq, dfn_dba, dfn_dbw, kp = Jq, -C, np.zeros((3, 3)), 0.0
        for rows, k in ((slice(3, 6), dt), (slice(0, 3), kp)):
            if k:
                F[rows, 6:10] += k * dfn_dq
                F[rows, 10:13] += k * dfn_dba
                F[rows, 13:16] += k * dfn_dbw
        return F

    # noise: Q and Q_inputs in ins_noise.py (InsNoise)

    # ------------------------------------------------------------------ input
    def input_from(self, message: Message) -> np.ndarray:
        """u (6,) from an IMU message ``ax ay az gx gy gz`` (m/s^2, rad/s, FRD). Raises MalformedMessage for a
        wrong count or a non-number, RejectedMessage (a MalformedMessage) for a non-finite value or one
        beyond ``max_specific_force`` / ``max_rate``: the sample is counted, never integrated."""
        vals = message.values
        if _KERNEL is not None and _KERNEL.imu_ok(vals, self._lim_f, self._lim_w):   # the usual sample, ~0.1 us
            return np.array(vals)
        if len(vals) != 6:
            raise MalformedMessage(f"process 'ins' expects 6 IMU values (ax ay az gx gy gz), got {len(vals)}")
        # plain floats first (the parser's tuple): these checks cost ~1 us, numpy's ~10, and the array is
        # made once, at the end
        ax, ay, az, gx, gy, gz = vals
        if not (ax.__class__ is float and ay.__class__ is float and az.__class__ is float
                and gx.__class__ is float and gy.__class__ is float and gz.__class__ is float):
            try:                                     # ints, numpy scalars (a message from another source)
                u = np.array(vals, dtype=float)
            except (TypeError, ValueError):          # a label
                raise MalformedMessage(f"expected numbers, got {vals!r}") from None
            if u.shape != (6,):                      # sequences for numbers
                raise MalformedMessage(f"expected numbers, got {vals!r}")
            ax, ay, az, gx, gy, gz = u.tolist()
        total = ax + ay + az + gx + gy + gz
        if total - total != 0.0:                     # a nan or an inf among them
            raise RejectedMessage(f"non-finite IMU value in {vals!r}")
        lim = self._max_f
        if lim is not None and not (abs(ax) <= lim and abs(ay) <= lim and abs(az) <= lim):
            raise RejectedMessage(f"specific force {[ax, ay, az]} beyond the sensor range +-{lim} m/s^2")
        lim = self._max_w
        if lim is not None and not (abs(gx) <= lim and abs(gy) <= lim and abs(gz) <= lim):
            raise RejectedMessage(f"angular rate {[gx, gy, gz]} beyond the sensor range +-{lim} rad/s")
        return np.array((ax, ay, az, gx, gy, gz))

    # ------------------------------------------------------------------ initial alignment
    def stillness(self, x0: np.ndarray, P0: np.ndarray, us: np.ndarray, ts: np.ndarray) -> tuple[bool, str] | None:
        """Whether the IMU samples ``us`` (k, 6) at times ``ts`` (k,) (s) of the alignment window are those of
        a static vehicle (fusion.api.ChecksStillness); ``(still, why)``, ``why`` naming the numbers.

        The test: per axis, the sample variance against what a static unit reads at that rate, ``N^2 / dt``
        for the white noise of density N plus ``N_b^2 T / 6`` for the bias walk over the window's T s, times
        :data:`STILL_SD_FACTOR` squared (chi-square on k - 1 dof at significance :data:`STILL_ALPHA`, six
        axes, Bonferroni). Motion that starts, stops or turns within the window spreads the samples far
        beyond that. Not tested: the mean rate (a turn at one constant rate over the whole window reads like
        a bias; the configured ``initial.sd.bw`` is the bias sd after this alignment, not a turn-on bias
        spread the mean could be tested against: the shipped car's 0.02 rad/s turn-on bias is 10 of it).
        None (no static assumption to test) with ``align_gyro_bias: false`` (a window in flight:
        docs/import.md) or fewer than 10 samples.
        """
        us, ts = np.asarray(us, dtype=float), np.asarray(ts, dtype=float)
        if not self.params.align_gyro_bias or len(us) < 10:  # type: ignore[attr-defined]
            return None
        from fusion.chisquare import chi2

        k, span = len(us), float(ts[-1] - ts[0])
        steps = np.diff(ts)
        steps = steps[steps > 0]
        if not steps.size:
            return None
        dt = float(np.median(steps))
        var = np.concatenate([self._var_a / dt + self._var_ba * span / 6.0,
                              self._var_w / dt + self._var_bw * span / 6.0])
        spread = us.var(axis=0, ddof=1)
        judged = var > 0.0                     # an axis with no noise given cannot be judged by its spread
        limit = chi2.ppf(1.0 - STILL_ALPHA / 6.0, k - 1) / (k - 1) * STILL_SD_FACTOR ** 2   # variance ratio
        ratio = np.where(judged, spread / np.where(judged, var, 1.0), 0.0)
        why = []
        names = ("ax", "ay", "az", "gx", "gy", "gz")
        for i in np.flatnonzero(ratio > limit):
            why.append(f"{names[i]} sd {np.sqrt(spread[i]):.3g} against {np.sqrt(var[i]):.3g} for a static unit "
                       f"({np.sqrt(ratio[i]):.1f}x, limit {np.sqrt(limit):.1f}x)")
        head = f"{k} IMU samples over {span:.2f} s"
        if why:
            return False, (f"{head}: " + "; ".join(why) + "; the gyro-bias prior is kept (the mean rate is motion) "
                           "and the yaw carried over the window by the gyros")
        return True, f"{head}: spread within {np.sqrt(ratio.max()):.1f}x a static unit's"

    def align(self, x0: np.ndarray, P0: np.ndarray, u_mean: np.ndarray, still: bool = True,
              window: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Initial alignment from the mean IMU sample ``u_mean`` (6,) of a static start (``initial.align_s``).

        Roll and pitch from gravity (levelling: a static accelerometer reads ``C_n^b (-g_n) + b_a``, with
        b_a the initial mean ``ba``); yaw is kept from ``x0`` (the config's initial attitude: gravity
        cannot give it). With ``align_gyro_bias`` the gyro bias becomes the mean rate (minus the Earth rate
        when modelled): a static gyro reads its bias, to ARW / sqrt(T) over T seconds. Accelerometer
        biases are left as given (not separable from tilt). P0 is returned unchanged.

        ``still=False`` (the window failed :meth:`stillness`): the mean rate is motion, so the gyro bias
        prior is kept; levelling stays (gravity still dominates the mean specific force: a mean acceleration
        a tilts it by a / g, 0.6 deg for 1 m/s gained in 9 s) and, given the ``window``'s samples ``(us (k, 6),
        ts (k,))``, the config's yaw, which is the window's first sample's, is carried to its end by the
        rotation over the window (the rates minus the bias prior, each held to the next sample) about the
        vertical: its NED-down component at the levelled tilt."""
        x0 = np.array(x0, dtype=float, copy=True)
        u_mean = np.asarray(u_mean, dtype=float)
        yaw = float(quat.to_euler(x0[6:10])[2]) if np.any(x0[6:10]) else 0.0
        if not still and window is not None and len(window[0]) > 1:
            us, ts = np.asarray(window[0], dtype=float), np.asarray(window[1], dtype=float)
            rotation = (us[:-1, 3:] - x0[13:16]).T @ np.diff(ts)                   # rad, body frame
            down = quat.to_matrix(quat.from_gravity(u_mean[:3] - x0[10:13]))[2]   # yaw-free: C_b^n's third row
            yaw += float(down @ rotation)
        q = quat.from_gravity(u_mean[:3] - x0[10:13], yaw)
        x0[6:10] = q
        if self.params.align_gyro_bias and still:  # type: ignore[attr-defined]
            w_ie_b = quat.to_matrix(q).T @ self.w_ie if self.w_ie is not None else 0.0
            x0[13:16] = u_mean[3:] - w_ie_b
        return x0, np.array(P0, dtype=float, copy=True)
