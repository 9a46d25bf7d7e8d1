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

from typing import ClassVar

import numpy as np

from fusion.api import BuildContext, Message, Params, ProcessModel, StateLayout

from .ins import Ins, InsParams, _var

__all__ = ["InsStates"]

_LAYOUTS = {10: StateLayout.parse("p:3 v:3 q:4:quaternion"),
            22: StateLayout.parse("p:3 v:3 q:4:quaternion ba:3 bw:3 sa:3 sw:3")}


class InsStates(ProcessModel):
    """Strapdown INS with the 10- or 22-state set of paper 002 (eqs. 8, 11-13), NED / FRD.

    State: ``p`` (m, NED), ``v`` (m/s, NED), ``q`` (Hamilton, scalar first, C_b^n); with 22 states also
    ``ba`` (m/s^2), ``bw`` (rad/s) biases and ``sa``, ``sw`` scale factors (1 = nominal), FRD, per axis.
    Input ``u = [ax ay az gx gy gz]`` (m/s^2, rad/s, FRD). The integration, eta, gravity, Earth rate and
    the input checks are those of ``ins`` (same parameters); see the module docstring for the mapping.
    """

    name: ClassVar[str] = "ins"
    Params: ClassVar[type[Params]] = InsParams
    input_dim: int = 6
    linear: bool = False

    def __init__(self, params: InsParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        p: InsParams = self.params  # type: ignore[assignment]
        if p.states not in _LAYOUTS:
            raise ValueError(f"InsStates builds states 10 or 22, got {p.states}")
        self.states = p.states
        self.layout = _LAYOUTS[p.states]
        self.core = Ins(p.model_copy(update={"states": 16, "accel_scale_rw": 0.0, "gyro_scale_rw": 0.0}), context)
        self.g, self.g_n = self.core.g, self.core.g_n
        self.counters = self.core.counters
        self._var_s = np.concatenate([_var(p.accel_scale_rw), _var(p.gyro_scale_rw)])

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

    def normalize(self, x: np.ndarray) -> np.ndarray:
        return self.core.normalize(x)

    def input_from(self, message: Message) -> np.ndarray:
        return self.core.input_from(message)

    # ------------------------------------------------------------------ linearisation and noise
    def jacobian(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """Analytic F = df/dx (n, n) at x (n,), from the 16-state F by the chain rule (module docstring)."""
        if u is None:
            raise ValueError("process 'ins' needs the IMU sample u = [ax ay az gx gy gz]")
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
        x16, ue = self._core(x, u if u is not None else np.zeros(6))
        return self._embed(self.core.Q(x16, ue, dt), dt)

    def Q_inputs(self, x0: np.ndarray, x1: np.ndarray, us: np.ndarray, dts: np.ndarray) -> np.ndarray:
        """Process noise (n, n) of a run of samples (the 16-state interval noise, ins_batch.interval_noise)."""
        a = np.zeros(16)
        b = np.zeros(16)
        a[:10], b[:10] = np.asarray(x0, float)[:10], np.asarray(x1, float)[:10]
        return self._embed(self.core.Q_inputs(a, b, us, dts), float(np.sum(dts)))

    # ------------------------------------------------------------------ initial alignment
    def align(self, x0: np.ndarray, P0: np.ndarray, u_mean: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Levelling from the mean static IMU sample (``Ins.align``): roll and pitch from gravity corrected
        by the initial bias and scale factor, yaw kept; with 22 states and ``align_gyro_bias`` the gyro bias
        becomes the mean static rate (a static gyro reads b, whatever its scale)."""
        x0 = np.array(x0, dtype=float, copy=True)
        u = np.array(u_mean, dtype=float, copy=True)
        x16 = np.zeros(16)
        x16[:10] = x0[:10]
        if self.states == 22:
            ba, sa = x0[10:13], x0[16:19]
            x16[10:16] = x0[10:16]
            u[:3] = ba + (u[:3] - ba) / sa                       # so that u - ba = (u~ - ba) / sa
        y, _ = self.core.align(x16, np.eye(16), u)
        x0[:10] = y[:10]
        if self.states == 22:
            x0[10:16] = y[10:16]
        return x0, np.array(P0, dtype=float, copy=True)
