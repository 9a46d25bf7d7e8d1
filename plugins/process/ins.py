"""Process ``ins``: IMU-driven 16-state strapdown INS (paper 000, sec. V-A, eqs. 33-52)."""
from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from fusion import quaternion as quat
from fusion.api import BuildContext, MalformedMessage, Message, Params, ProcessModel, RejectedMessage, StateLayout

from .ins_batch import K10T as _K10T, T16T as _T16T, add_hold_noise, integrate_inputs, interval_noise

STANDARD_GRAVITY = 9.80665          # m/s^2
EARTH_RATE = 7.292115e-5            # rad/s (WGS84)

# ADIS16364 data sheet (Analog Devices, Rev. B): angular random walk 2.0 deg/sqrt(h), velocity random walk
# 0.12 m/s/sqrt(h), in-run bias stability 25 deg/h and 0.1 mg. The bias random-walk densities are those
# stabilities spread over ~100 s (stability / sqrt(100 s)), a common engineering reading of the sheet.
ADIS16364_GYRO_ND = 2.0 * np.pi / 180.0 / 60.0            # rad/s/sqrt(Hz)  (= 5.82e-4)
ADIS16364_ACCEL_ND = 0.12 / 60.0                          # m/s^2/sqrt(Hz)  (= 2.0e-3)
ADIS16364_GYRO_BIAS_RW = 25.0 * np.pi / 180.0 / 3600.0 / 10.0   # rad/s^2/sqrt(Hz) (= 1.2e-5)
ADIS16364_ACCEL_BIAS_RW = 0.1e-3 * STANDARD_GRAVITY / 10.0      # m/s^3/sqrt(Hz)  (= 9.8e-5)

Density = float | tuple[float, float, float]



def somigliana_gravity(latitude_deg: float, height_m: float = 0.0) -> float:
    """Normal gravity (m/s^2) on the WGS84 ellipsoid (Somigliana) with the free-air correction -3.086e-6 h."""
    s2 = np.sin(np.radians(latitude_deg)) ** 2
    g0 = 9.7803253359 * (1.0 + 0.00193185265241 * s2) / np.sqrt(1.0 - 0.00669437999013 * s2)
    return float(g0 - 3.086e-6 * height_m)


class InsParams(Params):
    """YAML parameters of ``ins``. Noise densities are one value (all axes) or three (x y z, FRD).

    Data-sheet conversions: ARW [deg/sqrt(h)] * pi/180 / 60 = rad/s/sqrt(Hz);
    VRW [m/s/sqrt(h)] / 60 = m/s^2/sqrt(Hz). Defaults are ADIS16364-class figures.
    """

    gravity: float | None = Field(None, gt=0, description="local gravity g (m/s^2); default: from latitude, "
                                  "else the system's gravity (context.extra['gravity']), else 9.80665")
    latitude_deg: float | None = Field(None, ge=-90, le=90, description="latitude (deg) for g and Earth rate")
    height_m: float = Field(0.0, description="ellipsoidal height (m) for g from latitude")
    earth_rate: bool = Field(False, description="subtract the Earth rate C_n^b w_ie (eq. 38; needs latitude)")
    eta: float = Field(0.0, ge=0, description="quaternion norm-correction gain eta (1/s) of eq. 50; eta*dt < 1")
    integration: Literal["euler", "trapezoidal"] = Field(
        "euler", description="euler: eqs. 40-41 as in the paper; trapezoidal: mean of C_k f and C_k+1 f, "
        "p += v dt + a dt^2/2 (second order)")
    accel_noise_density: Density = Field(ADIS16364_ACCEL_ND, description="white noise of f (m/s^2/sqrt(Hz))")
    gyro_noise_density: Density = Field(ADIS16364_GYRO_ND, description="white noise of w (rad/s/sqrt(Hz))")
    accel_bias_rw: Density = Field(ADIS16364_ACCEL_BIAS_RW, description="accel bias random walk (m/s^3/sqrt(Hz))")
    gyro_bias_rw: Density = Field(ADIS16364_GYRO_BIAS_RW, description="gyro bias random walk (rad/s^2/sqrt(Hz))")
    quat_norm_variance: float = Field(0.0, ge=0, description="variance added along q per step so Q is "
                                      "positive definite (the norm direction is otherwise noise-free)")
    max_specific_force: float | None = Field(None, gt=0, description="sensor range (m/s^2, any axis)")
    max_rate: float | None = Field(None, gt=0, description="sensor range (rad/s, any axis)")
    hold_after: float | None = Field(None, gt=0, description="s: a sample held longer than this (an IMU gap) "
                                     "adds hold noise over the excess time (None: never)")
    hold_accel_rw: float = Field(0.7, ge=0, description="m/s^3/sqrt(Hz): random walk of the true specific "
                                 "force away from a held sample (the vehicle's manoeuvres)")
    hold_rate_rw: float = Field(1.0, ge=0, description="rad/s^2/sqrt(Hz): the same for the angular rate")
    align_gyro_bias: bool = Field(True, description="initial alignment also takes the mean static gyro "
                                  "rate as the gyro bias")
    states: Literal[10, 16, 22] = Field(16, description="state set (paper 002): 10 [p v q], 16 + biases "
                                        "[ba bw], 22 + scale factors [sa sw] (eqs. 11-13); see ins_states.py")
    accel_scale_rw: Density = Field(0.0, description="22 states: accelerometer scale-factor random walk "
                                    "(1/s^0.5, eq. 13)")
    gyro_scale_rw: Density = Field(0.0, description="22 states: gyro scale-factor random walk (1/s^0.5, eq. 13)")
    renormalize: bool = Field(True, description="bring the mean quaternion back to unit norm after each "
                              "step; false leaves the norm to eq. 50 (eta) or the quat_norm pseudo-observation")

    @model_validator(mode="after")
    def _earth_rate_needs_latitude(self) -> "InsParams":
        if self.earth_rate and self.latitude_deg is None:
            raise ValueError("earth_rate: true needs latitude_deg")
        if self.states != 22 and (np.any(np.asarray(self.accel_scale_rw)) or np.any(np.asarray(self.gyro_scale_rw))):
            raise ValueError("accel_scale_rw / gyro_scale_rw need states: 22 (the scale-factor states)")
        return self


def density_variance(density: Density) -> np.ndarray:
    d = np.broadcast_to(np.asarray(density, dtype=float), (3,))
    if np.any(d < 0):
        raise ValueError(f"noise densities must be >= 0, got {density}")
    return d * d


class Ins(ProcessModel):
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
    clamped to 0.5 (dead-beat) and counted in ``counters["eta_clamped"]``.

    Noise ``Q(x, u, dt)``, from continuous white-noise densities N (YAML): accelerometer N_a enters v
    as in the integrated double integrator (Q_vv = C N_a^2 C^T dt, Q_pv = Q_vv dt/2, Q_pp = Q_vv dt^2/3);
    gyro N_w enters q through ``dq/dw = Xi(q) dt/2`` (first order): Q_qq = (dt/4) Xi(q) N_w^2 Xi(q)^T
    (rank 3: nothing along q itself, plus ``quat_norm_variance`` q q^T/|q|^2 if set); biases
    Q_ba = N_ba^2 dt, Q_bw = N_bw^2 dt (eqs. 51-52 with W of variance N^2/dt). Cross terms between the
    bias random walks and v, q are second order in dt and neglected. A sample held past ``hold_after``
    (an IMU gap) adds hold noise (``ins_batch.add_hold_noise``).

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
    linear: bool = False

    def __new__(cls, params: InsParams | None = None, context: BuildContext | None = None):
        """``states: 10`` or ``22`` build the paper-002 state sets (ins_states.InsStates, which drives this
        16-state model underneath); 16 is this class as it is."""
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
        self.counters: dict[str, int] = {"eta_clamped": 0}
        self._max_f, self._max_w = p.max_specific_force, p.max_rate
        self._hold = p.hold_after

    # ------------------------------------------------------------------ propagation
    def _eta_dt(self, dt: float) -> float:
        e = self.params.eta * dt  # type: ignore[attr-defined]
        if e >= 1.0:
            self.counters["eta_clamped"] += 1
            return 0.5
        return e

    def f(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """Propagate states x (..., 16) over dt (s) with the IMU sample u (6,) or (..., 6); see the class doc.

        Evaluated once on the whole sigma-point array, stored component-first ((16, N)), so each line is
        one numpy call on whole rows: no loop over points, no stacked 4x4 products."""
        if u is None:
            raise ValueError("process 'ins' needs the IMU sample u = [ax ay az gx gy gz]")
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

        Vectorised over the samples as well as the points (``ins_batch.integrate_inputs``: within a run
        the biases are constant and the rotation increments do not depend on the attitude). With eta > 0
        (|q| enters every step) or the Earth rate (it depends on the attitude): k calls of :meth:`f`."""
        us = np.asarray(us, dtype=float)
        dts = np.asarray(dts, dtype=float)
        x = np.asarray(x, dtype=float)
        if dts.shape[0] == 1 or self.params.eta or self.w_ie is not None:  # type: ignore[attr-defined]
            for u, dt in zip(us, dts):
                x = self.f(x, u, dt)
            return x
        return integrate_inputs(x, us, dts, self._g_col, self._trap)

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
        """Analytic F = df/dx (16, 16) at x (16,) (for the EKF), consistent with f including eq. 50."""
        if u is None:
            raise ValueError("process 'ins' needs the IMU sample u = [ax ay az gx gy gz]")
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

    # ------------------------------------------------------------------ noise
    def Q(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """Discrete process noise (16, 16) over dt (s) at x (16,); see the class doc for the discretisation.

        The attitude-independent blocks are cached per power of dt; with isotropic gyro noise the q block
        is ``N_w^2 dt / 4 (|q|^2 I - q q^T)`` (= Xi N_w^2 Xi^T: the columns of [q, Xi(q)] are orthogonal)."""
        q = np.asarray(x, dtype=float)[6:10]
        Qm = self._Qdt[0] * dt
        if self._Qdt[1] is not None:
            Qm += self._Qdt[1] * (dt * dt)
            Qm += self._Qdt[2] * (dt * dt * dt)
        else:
            C = quat.to_matrix(q)
            Sa = (C * self._var_a) @ C.T
            Qm[3:6, 3:6] = Sa * dt
            Qm[0:3, 3:6] = Qm[3:6, 0:3] = Sa * (dt * dt / 2.0)
            Qm[0:3, 0:3] = Sa * (dt**3 / 3.0)
        qq = q[:, None] * q
        if self._iso_w:
            Qqq = (np.diag(np.full(4, q @ q)) - qq) * (self._var_w[0] * dt / 4.0)
        else:
            q0, q1, q2, q3 = q
            Xi = np.array([[-q1, -q2, -q3], [q0, -q3, q2], [q3, q0, -q1], [-q2, q1, q0]])   # q (x) [0, v] = Xi v
            Qqq = (Xi * self._var_w) @ Xi.T * (dt / 4.0)
            Qqq = 0.5 * (Qqq + Qqq.T)
        qnv = self.params.quat_norm_variance  # type: ignore[attr-defined]
        if qnv:
            Qqq += qq * (qnv / (q @ q))
        Qm[6:10, 6:10] = Qqq
        if self._hold is not None and dt > self._hold:
            add_hold_noise(Qm, q, dt - self._hold, self.params.hold_accel_rw, self.params.hold_rate_rw)  # type: ignore[attr-defined]
        return Qm

    def Q_inputs(self, x0: np.ndarray, x1: np.ndarray, us: np.ndarray, dts: np.ndarray) -> np.ndarray:
        """Process noise (16, 16) of a run of samples integrated in one step (:meth:`f_inputs`), from the
        mean before (x0) and after (x1) the run: the white noises and bias random walks of the whole
        interval T = sum dts propagated through the linearised error dynamics (gyro noise tilts the
        specific force into v, early accelerometer noise moves p by the end), exactly for a constant
        specific force (``ins_batch.interval_noise``). For one sample it is :meth:`Q` plus the couplings
        of order dt^2 and higher that :meth:`Q` leaves to the propagation of later steps."""
        Qm = interval_noise(x0, x1, dts, self.g_n, self._var_a, self._var_w, self._var_ba, self._var_bw,
                            self._qc_diag, self.params.quat_norm_variance)  # type: ignore[attr-defined]
        if self._hold is not None:
            e = float(np.maximum(np.asarray(dts) - self._hold, 0.0).sum())
            if e > 0.0:
                add_hold_noise(Qm, np.asarray(x1, dtype=float)[6:10], e, self.params.hold_accel_rw,  # type: ignore[attr-defined]
                               self.params.hold_rate_rw)  # type: ignore[attr-defined]
        return Qm

    # ------------------------------------------------------------------ input
    def input_from(self, message: Message) -> np.ndarray:
        """u (6,) from an IMU message ``ax ay az gx gy gz`` (m/s^2, rad/s, FRD). Raises MalformedMessage for a
        wrong count or a non-number, RejectedMessage (a MalformedMessage) for a non-finite value or one
        beyond ``max_specific_force`` / ``max_rate``: the sample is counted, never integrated."""
        vals = message.values
        if len(vals) != 6:
            raise MalformedMessage(f"process 'ins' expects 6 IMU values (ax ay az gx gy gz), got {len(vals)}")
        try:
            u = np.array(vals, dtype=float)
        except (TypeError, ValueError):
            raise MalformedMessage(f"expected numbers, got {vals!r}") from None
        if u.shape != (6,):                          # sequences for numbers (a message from another source)
            raise MalformedMessage(f"expected numbers, got {vals!r}")
        ax, ay, az, gx, gy, gz = u.tolist()          # plain floats: these checks cost ~1 us, numpy's ~10
        total = ax + ay + az + gx + gy + gz
        if total - total != 0.0:                     # a nan or an inf among them
            raise RejectedMessage(f"non-finite IMU value in {vals!r}")
        lim = self._max_f
        if lim is not None and not (abs(ax) <= lim and abs(ay) <= lim and abs(az) <= lim):
            raise RejectedMessage(f"specific force {[ax, ay, az]} beyond the sensor range +-{lim} m/s^2")
        lim = self._max_w
        if lim is not None and not (abs(gx) <= lim and abs(gy) <= lim and abs(gz) <= lim):
            raise RejectedMessage(f"angular rate {[gx, gy, gz]} beyond the sensor range +-{lim} rad/s")
        return u

    # ------------------------------------------------------------------ initial alignment
    def align(self, x0: np.ndarray, P0: np.ndarray, u_mean: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Initial alignment from the mean IMU sample ``u_mean`` (6,) of a static start (``initial.align_s``).

        Roll and pitch from gravity (levelling: a static accelerometer reads ``C_n^b (-g_n) + b_a``, with
        b_a the initial mean ``ba``); yaw is kept from ``x0`` (the config's initial attitude: gravity
        cannot give it). With ``align_gyro_bias`` the gyro bias becomes the mean rate (minus the Earth rate
        when modelled): a static gyro reads its bias, to ARW / sqrt(T) over T seconds. Accelerometer
        biases are left as given (not separable from tilt). P0 is returned unchanged."""
        x0 = np.array(x0, dtype=float, copy=True)
        u_mean = np.asarray(u_mean, dtype=float)
        yaw = float(quat.to_euler(x0[6:10])[2]) if np.any(x0[6:10]) else 0.0
        q = quat.from_gravity(u_mean[:3] - x0[10:13], yaw)
        x0[6:10] = q
        if self.params.align_gyro_bias:  # type: ignore[attr-defined]
            w_ie_b = quat.to_matrix(q).T @ self.w_ie if self.w_ie is not None else 0.0
            x0[13:16] = u_mean[3:] - w_ie_b
        return x0, np.array(P0, dtype=float, copy=True)
