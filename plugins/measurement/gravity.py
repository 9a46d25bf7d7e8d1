"""Measurement ``gravity``: the accelerometer's specific force as a measurement of attitude (roll and pitch).

At rest an accelerometer reads the specific force ``f_b = -C_n^b g_n`` (FRD body frame, m/s^2; NED with
``g_n = [0, 0, g]``, the sign of the ``ins`` process, whose velocity equation is ``v' = C_b^n f + g_n``, and
of ``solvers.triad``: body gravity ``-f_b``). So, with ``c = C_b^n(q)^T [0, 0, 1]`` (the third row of
C_b^n computed from q / |q|)::

    z = f_b,   h(x) = -g c(q),   dh/dq = -g (dc/dq / |q|^2 - c 2 q^T / |q|^4)       (analytic)

A moving body adds its linear acceleration ``C_n^b a_n`` to z, an error h does not model. It is coloured (a
hand's motion is correlated over a fraction of a second), so it enters R as the white noise of the same
low-frequency power (Gelb, Applied Optimal Estimation, sec. 4.5: a first-order Gauss-Markov process of sd
s and correlation time tau acts, over times much longer than tau, as white noise of PSD 2 s^2 tau, i.e. of
variance ``2 s^2 tau / dt`` a sample of spacing dt). Per sample (the adaptive R of Sabatini, IEEE TBME 53(7),
2006, sec. II-D: the accelerometer is trusted less when ``|f|`` departs from g)::

    R = noise_sd^2 I + max(1, 2 motion_tau / dt) (motion_sd^2 + (|f| - g)^2) I

``motion_sd`` is the floor of the motion's acceleration (an acceleration across gravity barely changes
|f|: ``|f| ~ g + a_par + a_perp^2 / 2g``); ``(|f| - g)^2`` estimates the sample's own acceleration along
gravity, taken as the size of the other two components too (an isotropic motion). A sample with
``| |f| - g | > max_deviation`` is rejected (counted, the attitude left to the gyros): Sabatini's switch of
the accelerometer's covariance to infinity past a threshold on ``| |f| - g |``. The ``ahrs`` package's EKF
(ahrs.filters.EKF) uses one fixed accelerometer variance instead; both agree at rest.

Messages: ``ax ay az`` (m/s^2, FRD), or a whole IMU line ``ax ay az gx gy gz`` (the rates are ignored).
"""
from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from pydantic import Field

from fusion.api import (BuildContext, ConfigError, MalformedMessage, MeasurementModel, Message, Observation, Params,
                        RejectedMessage)

# MPU-9250 (InvenSense PS-MPU-9250A-01 rev 1.1, table 2): accelerometer noise power spectral density
# 300 ug/sqrt(Hz); at 100 Hz a sample's sd is 300e-6 * 9.80665 * sqrt(100) = 0.029 m/s^2
MPU9250_ACCEL_ND = 300e-6 * 9.80665          # m/s^2/sqrt(Hz)


class GravityParams(Params):
    """YAML parameters of ``gravity`` (m/s^2, s)."""

    noise_sd: float = Field(0.03, gt=0, description="accelerometer white noise sd of one sample (m/s^2) = "
                            "noise density (m/s^2/sqrt(Hz)) * sqrt(sample rate)")
    motion_sd: float = Field(0.5, ge=0, description="sd of the body's linear acceleration (m/s^2) the norm "
                             "test cannot see (across gravity); 0 for a body at rest")
    motion_tau: float = Field(0.5, ge=0, description="correlation time of that acceleration (s); 0: white")
    adaptive: bool = Field(True, description="add (|f| - g)^2 to the motion's variance, sample by sample")
    max_deviation: float | None = Field(2.0, gt=0, description="reject a sample whose | |f| - g | exceeds this "
                                        "(m/s^2); none: keep every sample")
    gravity: float | None = Field(None, gt=0, le=30, description="g (m/s^2); none: the recording's header "
                                  "(# gravity), else 9.80665")


class Gravity(MeasurementModel):
    """Accelerometer gravity direction, ``z = f_b ~ -C_n^b(q) g_n`` (FRD, m/s^2) with an adaptive R for the
    body's linear acceleration and a gate on ``|f|`` (module docstring). Needs an attitude block ``q``."""

    name: ClassVar[str] = "gravity"
    Params: ClassVar[type[Params]] = GravityParams
    carries_R = True          # R is built per sample from the parameters (the sensor's noise is not used)
    dim: int = 3

    def __init__(self, params: GravityParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        layout = self.context.layout
        if layout is None or "q" not in layout or layout.block("q").kind != "quaternion":
            raise ConfigError("gravity needs a state with an attitude quaternion block 'q'")
        self._q = layout["q"]
        self._i = self._q.start
        self.n = layout.n
        p: GravityParams = self.params  # type: ignore[assignment]
        self.g = float(p.gravity if p.gravity is not None else self.context.extra.get("gravity", 9.80665))
        self._t_last: float | None = None

    def h(self, x: np.ndarray) -> np.ndarray:
        """Predicted specific force (..., 3) (m/s^2, FRD) for states x (..., n)."""
        x = np.asarray(x, dtype=float)
        if x.ndim == 1:
            w, a, b, c = x[self._i:self._i + 4].tolist()
            k = -self.g / (w * w + a * a + b * b + c * c)
            return np.array([2.0 * (a * c - w * b) * k, 2.0 * (b * c + w * a) * k, (w * w - a * a - b * b + c * c) * k])
        q = x[..., self._q]
        w, a, b, c = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
        k = -self.g / (w * w + a * a + b * b + c * c)
        return np.stack([2.0 * (a * c - w * b) * k, 2.0 * (b * c + w * a) * k, (w * w - a * a - b * b + c * c) * k],
                        axis=-1)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """dh/dx (3, n) at x (n,) (analytic)."""
        w, a, b, c = np.asarray(x, dtype=float)[self._i:self._i + 4].tolist()
        n2 = w * w + a * a + b * b + c * c
        cv = np.array([2.0 * (a * c - w * b), 2.0 * (b * c + w * a), w * w - a * a - b * b + c * c])
        dc = 2.0 * np.array([[-b, c, -w, a], [a, w, c, b], [w, -a, -b, c]])
        H = np.zeros((3, self.n))
        H[:, self._q] = (-self.g / n2) * (dc - np.outer(cv, [w, a, b, c]) * (2.0 / n2))
        return H

    def noise(self, f: np.ndarray, dt: float | None) -> np.ndarray:
        """R (3, 3) (m^2/s^4) of a sample f (3,) a time dt (s) after the previous one (None: the first)."""
        p: GravityParams = self.params  # type: ignore[assignment]
        dev = math.sqrt(float(f @ f)) - self.g
        var = p.motion_sd ** 2 + (dev * dev if p.adaptive else 0.0)
        if p.motion_tau > 0.0:
            var *= max(1.0, 2.0 * p.motion_tau / (dt if dt is not None and dt > 0.0 else p.motion_tau))
        return np.eye(3) * (p.noise_sd ** 2 + var)

    def observe(self, message: Message) -> Observation | None:
        """Observation of ``ax ay az [gx gy gz]`` (m/s^2 FRD) with its own R; RejectedMessage past the gate."""
        v = message.floats()
        if v.shape not in ((3,), (6,)) or not np.all(np.isfinite(v)):
            raise MalformedMessage(f"gravity expects 3 finite values ax ay az (or an IMU line of 6), got "
                                   f"{message.values!r}")
        f = v[:3]
        dt = None if self._t_last is None else message.t - self._t_last
        self._t_last = message.t
        p: GravityParams = self.params  # type: ignore[assignment]
        dev = abs(math.sqrt(float(f @ f)) - self.g)
        if p.max_deviation is not None and dev > p.max_deviation:
            raise RejectedMessage(f"gravity: |f| departs from g by {dev:.2f} m/s^2 (max_deviation "
                                  f"{p.max_deviation:g}): the body accelerates, the sample is not used")
        return Observation(message.t, f, self, self.noise(f, dt))
