"""IMU simulator: specific force and angular rate in the body frame, with the usual MEMS errors."""
from __future__ import annotations

import numpy as np
from pydantic import Field, field_validator

from fusion.simulate.base import SensorOutput, SensorSimulator, SimContext, SimParams, sample_times

Vec3 = list[float]


class ImuParams(SimParams):
    rate_hz: float = Field(100.0, gt=0, description="sample rate (Hz)")
    accel_noise_density: float = Field(0.002, ge=0, description="accelerometer white noise (m/s^2/sqrt(Hz)); "
                                       "= velocity random walk (m/s/sqrt(hr)) / 60")
    gyro_noise_density: float = Field(5.8e-4, ge=0, description="gyro white noise (rad/s/sqrt(Hz)); "
                                      "= angle random walk (deg/sqrt(hr)) / 60 * pi / 180")
    accel_bias: Vec3 | None = Field(None, description="turn-on accelerometer bias (m/s^2); None: drawn "
                                                      "from accel_bias_sd")
    accel_bias_sd: float = Field(0.0, ge=0, description="sd of the drawn turn-on accelerometer bias (m/s^2)")
    gyro_bias: Vec3 | None = Field(None, description="turn-on gyro bias (rad/s); None: drawn from gyro_bias_sd")
    gyro_bias_sd: float = Field(0.0, ge=0, description="sd of the drawn turn-on gyro bias (rad/s)")
    accel_bias_rw: float = Field(0.0, ge=0, description="accelerometer bias random walk (m/s^3/sqrt(Hz))")
    gyro_bias_rw: float = Field(0.0, ge=0, description="gyro bias random walk (rad/s^2/sqrt(Hz))")
    accel_scale_sd: float = Field(0.0, ge=0, description="sd of the accelerometer scale-factor error (1 = 100%)")
    gyro_scale_sd: float = Field(0.0, ge=0, description="sd of the gyro scale-factor error (1 = 100%)")
    accel_scale_rw: float = Field(0.0, ge=0, description="random walk of each accelerometer scale factor "
                                  "(1/sqrt(s); paper 002 eq. 13, the ins process's accel_scale_rw)")
    gyro_scale_rw: float = Field(0.0, ge=0, description="random walk of each gyro scale factor (1/sqrt(s))")
    misalignment_sd: float = Field(0.0, ge=0, description="sd of the axis misalignments (rad)")
    accel_range: float | None = Field(None, gt=0, description="saturation of each accelerometer axis (m/s^2)")
    gyro_range: float | None = Field(None, gt=0, description="saturation of each gyro axis (rad/s)")

    @field_validator("accel_bias", "gyro_bias")
    @classmethod
    def _three(cls, v):
        if v is not None and len(v) != 3:
            raise ValueError(f"expected 3 values (x, y, z), got {len(v)}")
        return v


class ImuSimulator(SensorSimulator):
    """Strapdown IMU: fields ``ax ay az gx gy gz`` (m/s^2, rad/s; FRD body frame).

    Exact values from the trajectory: specific force ``f_b = C_n^b (a_n - g_n)`` with ``g_n = [0, 0, g]``
    (NED), angular rate ``w_b`` of the body relative to NED (Earth rate neglected). Measured:
    ``(I + S + M) f_b + b_a(t) + n_a`` (and the same for the gyros) with scale factors S (diagonal),
    misalignments M (off-diagonal), a turn-on bias plus a random walk b(t), white noise of the given
    density (sd = density * sqrt(rate)), and optional saturation. The scale factors may random-walk too
    (``accel_scale_rw``, ``gyro_scale_rw``: S_ii(t), steps of sd rw sqrt(dt) from the turn-on draw). The
    true biases go to the truth lines as ``bax bay baz bwx bwy bwz`` (the INS state blocks ba, bw) and,
    when scale errors are simulated, the scale factors ``sax say saz swx swy swz`` (``s = 1 + S_ii``,
    paper 002 eq. 11: ``f~ = s f + b + w``; at the truth's times when they walk).
    ``--noise off`` makes every sample exact.
    """

    name = "imu"
    Params = ImuParams

    def fields(self, sim: SimContext) -> tuple[str, ...]:
        return ("ax", "ay", "az", "gx", "gy", "gz")

    def header(self, sim: SimContext) -> list[str]:
        p = self.params
        s = self.context.sensor
        on = sim.noise
        return [f"{s} rate_hz: {p.rate_hz:g}",
                f"{s} accel_noise_density: {p.accel_noise_density if on else 0:g}",
                f"{s} gyro_noise_density: {p.gyro_noise_density if on else 0:g}",
                f"{s} accel_bias_rw: {p.accel_bias_rw if on else 0:g}",
                f"{s} gyro_bias_rw: {p.gyro_bias_rw if on else 0:g}"]

    def _bias(self, rng, fixed, sd, rw, n, dt) -> np.ndarray:
        b0 = np.asarray(fixed, float) if fixed is not None else rng.normal(0.0, sd, 3)
        steps = rng.normal(0.0, rw * np.sqrt(dt), (n, 3))
        steps[0] = 0.0
        return b0 + np.cumsum(steps, axis=0)

    def _errors(self, rng, scale_sd, mis_sd) -> np.ndarray:
        E = np.diag(rng.normal(0.0, scale_sd, 3))
        off = rng.normal(0.0, mis_sd, 6)
        E[0, 1], E[0, 2], E[1, 0], E[1, 2], E[2, 0], E[2, 1] = off
        return E

    def simulate(self, sim: SimContext) -> SensorOutput:
        p = self.params
        t = sample_times(p.rate_hz, sim.duration)
        self._t = t
        kin = sim.kinematics(t)
        R = kin.rotation
        g_n = np.array([0.0, 0.0, sim.gravity])
        f = f_true = R.apply(kin.a - g_n, inverse=True)
        w = w_true = kin.w_b
        n = len(t)
        self._scale_t = None
        if sim.noise:
            r_ab, r_wb, r_an, r_wn, r_err = sim.rng.spawn(5)
            dt = 1.0 / p.rate_hz
            self._ba = self._bias(r_ab, p.accel_bias, p.accel_bias_sd, p.accel_bias_rw, n, dt)
            self._bw = self._bias(r_wb, p.gyro_bias, p.gyro_bias_sd, p.gyro_bias_rw, n, dt)
            Ea = self._errors(r_err, p.accel_scale_sd, p.misalignment_sd)
            Ew = self._errors(r_err, p.gyro_scale_sd, p.misalignment_sd)
            self._scale = np.concatenate([1.0 + np.diag(Ea), 1.0 + np.diag(Ew)])
            sq = np.sqrt(p.rate_hz)
            f = f + f @ Ea.T + self._ba + r_an.normal(0.0, p.accel_noise_density * sq, (n, 3))
            w = w + w @ Ew.T + self._bw + r_wn.normal(0.0, p.gyro_noise_density * sq, (n, 3))
            if p.accel_scale_rw > 0 or p.gyro_scale_rw > 0:   # drawn only then: the other scenarios' bytes stay
                (r_sw,) = sim.rng.spawn(1)
                dS = self._bias(r_sw, [0.0] * 3, 0.0, p.accel_scale_rw, n, dt)   # S_ii(t) - S_ii(0)
                dW = self._bias(r_sw, [0.0] * 3, 0.0, p.gyro_scale_rw, n, dt)
                f = f + dS * f_true
                w = w + dW * w_true
                self._scale_t = self._scale + np.column_stack([dS, dW])   # (n, 6): s(t) at the samples
        else:
            self._ba = np.zeros((n, 3))
            self._bw = np.zeros((n, 3))
            self._scale = np.ones(6)
        if p.accel_range is not None:
            f = np.clip(f, -p.accel_range, p.accel_range)
        if p.gyro_range is not None:
            w = np.clip(w, -p.gyro_range, p.gyro_range)
        vals = np.column_stack([f, w])
        return SensorOutput(t, vals.tolist())

    def _has_scale(self) -> bool:
        p = self.params
        return p.accel_scale_sd > 0 or p.gyro_scale_sd > 0 or p.accel_scale_rw > 0 or p.gyro_scale_rw > 0

    def truth_fields(self) -> tuple[str, ...]:
        names = ("bax", "bay", "baz", "bwx", "bwy", "bwz")
        return names + (("sax", "say", "saz", "swx", "swy", "swz") if self._has_scale() else ())

    def truth(self, t: np.ndarray) -> np.ndarray:
        B = np.column_stack([self._ba, self._bw])
        cols = [np.interp(t, self._t, B[:, i]) for i in range(6)]
        if self._has_scale() and self._scale_t is not None:
            cols += [np.interp(t, self._t, self._scale_t[:, i]) for i in range(6)]
        elif self._has_scale():
            cols += [np.full(len(t), s) for s in self._scale]
        return np.column_stack(cols)
