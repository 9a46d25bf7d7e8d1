"""The ``ins`` process noise (paper 000 eqs. 44-52): Q over one sample and over a run of samples, a mixin of
fusion_plugins.process.ins.Ins, whose attributes (noise variances, cached blocks) it uses."""
from __future__ import annotations

import numpy as np

from fusion import quaternion as quat

from .ins_batch import add_hold_noise, interval_noise


class InsNoise:
    """Mixin: ``Q`` and ``Q_inputs`` of :class:`fusion_plugins.process.ins.Ins`."""

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
            e0 = self._excess0            # how long past hold_after the sample already was (Ins.held)
            self._add_hold_noise(Qm, q, e0, e0 + dt - self._hold)
        return Qm

    def _add_hold_noise(self, Qm: np.ndarray, q: np.ndarray, e0: float, e1: float) -> None:
        """ins_batch.add_hold_noise with this model's hold parameters."""
        p = self.params
        add_hold_noise(Qm, q, e0, e1, p.hold_accel_sd, p.hold_yaw_rate_sd, p.hold_tilt_rate_sd,  # type: ignore[attr-defined]
                       p.hold_motion_tau, p.hold_max_attitude_sd)  # type: ignore[attr-defined]

    def Q_batch(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """:meth:`Q` for states x (N, 16) at once, (N, 16, 16) (batched filters, fusion.batch): with isotropic
        accelerometer and gyro noise and no hold noise, the shared blocks plus the attitude block of each
        state in one vectorised evaluation; otherwise :meth:`Q` state by state."""
        x = np.asarray(x, dtype=float)
        if self._Qdt[1] is None or not self._iso_w or (self._hold is not None and dt > self._hold):
            return np.stack([self.Q(xi, u if u is None or np.ndim(u) == 1 else u[i], dt) for i, xi in enumerate(x)])
        base = self._Qdt[0] * dt
        base += self._Qdt[1] * (dt * dt)
        base += self._Qdt[2] * (dt * dt * dt)
        q = x[:, 6:10]
        qq = q[:, :, None] * q[:, None, :]
        n2 = np.einsum("ki,ki->k", q, q)
        Qqq = (n2[:, None, None] * np.eye(4) - qq) * (self._var_w[0] * dt / 4.0)
        qnv = self.params.quat_norm_variance  # type: ignore[attr-defined]
        if qnv:
            Qqq += qq * (qnv / n2)[:, None, None]
        Qm = np.repeat(base[None], x.shape[0], axis=0)
        Qm[:, 6:10, 6:10] = Qqq
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
            q1 = np.asarray(x1, dtype=float)[6:10]
            for e in (np.asarray(dts, dtype=float) - self._hold).tolist():   # each sample of a run is a new one
                if e > 0.0:
                    self._add_hold_noise(Qm, q1, 0.0, e)
        return Qm
