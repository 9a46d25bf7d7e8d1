"""kf, ekf, ukf and srukf over a leading axis of N independent filters (see the package docstring).

Each class wraps the wired single filter it mirrors (its parameters and sigma-point weights) and follows
its equations line for line (plugins/filters/base.py, ekf.py, ukf.py, srukf.py); the differences are
only in how the algebra is stacked (``np.linalg`` gufuncs over N, a solve instead of two triangular
solves), which changes rounding, not numbers (tests/batch/: 1e-12).

Per-filter diagnostics are arrays (N,) in ``counters``: ``predicts``, ``updates``, ``rejected``,
``not_positive_definite``.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from fusion.api import ConfigError, Gate

from .belief import BatchBelief, BatchUpdate
from .heap import keep_heap
from .linalg import (T, cholesky, mm, psd_sqrt_rows, qr_lower, recover_factors, sigma_deviations, sigma_points,
                     sigma_points_cf, solve_spd, sym)
from .models import batch_F, batch_H, batch_Q, batch_R, propagate_cf

__all__ = ["BatchFilter", "BatchKF", "BatchEKF", "BatchUKF", "BatchSRUKF", "make_batch_filter", "batch_capable"]


class BatchFilter:
    """Base: the wrapped single filter ``single``, per-filter ``counters`` and the masked repairs."""

    name = ""

    def __init__(self, single: Any):
        self.single = single
        self.counters: dict[str, np.ndarray] = {}
        self.N = 0

    # ------------------------------------------------------------------ helpers
    def normalizer(self, model: Any):
        """The updated means' normalisation: the single filter's (its layout's quaternion blocks, else
        the measurement model's layout: plugins/filters/base.py ``KalmanBase.normalizer``), so that the
        batch stays equal to single filters."""
        return self.single.normalizer(model)

    def reset(self, N: int) -> None:
        """Zero the per-filter counters for a batch of N."""
        self.N = N
        self.counters = {k: np.zeros(N, np.int64) for k in ("predicts", "updates", "rejected", "not_positive_definite")}

    def _count(self, key: str, mask: np.ndarray | bool = True) -> None:
        if self.N == 0:
            raise RuntimeError("call initial_belief (or reset(N)) before predict/update")
        self.counters[key] += mask

    def factor(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Cholesky factors of P (N, n, n), the non-positive-definite ones repaired and counted; returns
        ``(L, repaired P or None)``."""
        if P.shape[-1] == 1:                               # m = 1 (a range): no LAPACK call
            ok = P[:, 0, 0] > 0.0
            if ok.all():
                return np.sqrt(P), None
            if not np.isfinite(P).all():
                raise FloatingPointError("innovation covariance holds NaN or inf")
            floor = np.maximum(1e-12 * np.abs(P[:, 0, 0]), np.finfo(float).tiny ** 0.5)
            rep = np.where(ok, P[:, 0, 0], np.maximum(P[:, 0, 0], floor))[:, None, None]
            self._count("not_positive_definite", ~ok)
            return np.sqrt(rep), rep
        L, ok = cholesky(P)
        if ok.all():
            return L, None
        bad = ~ok
        self._count("not_positive_definite", bad)
        L[bad] = recover_factors(P[bad])
        rep = P.copy()
        rep[bad] = L[bad] @ T(L[bad])
        return L, rep

    def gate_mask(self, nis: np.ndarray, gate: Gate | None, m: int) -> np.ndarray:
        """Accepted (N,) by the gate's threshold for dimension m (NaN rejected); counts rejections."""
        if gate is None:
            return np.ones(nis.shape[0], bool)
        ok = nis <= gate.threshold(m)
        self._count("rejected", ~ok)
        return ok

    # ------------------------------------------------------------------ interface
    def initial_belief(self, t: float, x: np.ndarray, P: np.ndarray) -> BatchBelief:
        """Batch of N initial beliefs: x (N, n), P (N, n, n) or a shared (n, n)."""
        x = np.array(x, dtype=float)
        P = np.broadcast_to(np.asarray(P, dtype=float), x.shape + x.shape[-1:])
        self.reset(x.shape[0])
        return BatchBelief(float(t), x, P=sym(P))

    def predict(self, b: BatchBelief, process: Any, u: np.ndarray | None, dt: float) -> BatchBelief:
        raise NotImplementedError

    def update(self, b: BatchBelief, model: Any, z: np.ndarray, R: Any, gate: Gate | None = None) -> BatchUpdate:
        raise NotImplementedError

    def predict_inputs(self, b: BatchBelief, process: Any, us: np.ndarray, dts: np.ndarray) -> BatchBelief:
        """A run of input samples ``us`` (k, m) shared or (k, N, m) per filter, one predict per sample."""
        for u, dt in zip(us, dts):
            b = self.predict(b, process, u, float(dt))
        return b

    def _linear_predict(self, b: BatchBelief, process: Any, u, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """x^- = normalize(f(x)), P^- = F P F^T + Q (paper 001 eqs. 9-10), symmetrised."""
        x = b.x
        F = batch_F(process, x, u, dt)
        Ft = F.T if F.ndim == 2 else T(F)
        P1 = sym(mm(mm(F, b.cov), Ft) + batch_Q(process, x, u, dt))
        return process.normalize(process.f(x, _per_point(u, x), dt)), P1


def _per_point(u, x: np.ndarray):
    """u broadcastable against states x (N, ..., n): per-filter inputs (N, m) gain the point axes."""
    if u is None:
        return None
    u = np.asarray(u, dtype=float)
    if u.ndim == 2 and x.ndim == 3:
        return u[:, None, :]
    return u


def _residual(model: Any):
    from fusion_plugins.filters.base import residual_of
    return residual_of(model)


class BatchEKF(BatchFilter):
    """Batched ekf (plugins/filters/ekf.py): F, H the models' Jacobians at each filter's mean; Joseph form."""

    name = "ekf"

    def predict(self, b: BatchBelief, process: Any, u, dt: float) -> BatchBelief:
        if dt == 0.0:
            return b
        x1, P1 = self._linear_predict(b, process, u, dt)
        self._count("predicts")
        return BatchBelief(b.t + dt, x1, P=P1)

    def update(self, b: BatchBelief, model: Any, z, R, gate: Gate | None = None) -> BatchUpdate:
        x, P = b.x, b.cov
        N = x.shape[0]
        z = np.asarray(z, dtype=float).reshape(N, -1)
        m = z.shape[1]
        R = batch_R(R, m, N)
        H = batch_H(model, x)                                # (N, m, n)
        HP = H @ P
        S = HP @ T(H) + R                                    # S = H P H^T + R
        _, rep = self.factor(S)
        if rep is not None:
            S = rep
        r = _residual(model)(z, model.h(x))                  # y = residual(z, h(x^-))
        Kt = solve_spd(S, HP)                                # K^T = S^-1 H P  (N, m, n)
        nis = np.einsum("km,km->k", r, solve_spd(S, r[:, :, None])[:, :, 0])
        ok = self.gate_mask(nis, gate, m)
        x1 = x + np.einsum("kmn,km->kn", Kt, r)
        A = np.eye(x.shape[1]) - T(Kt) @ H                   # I - K H
        P1 = sym(A @ P @ T(A) + T(Kt) @ R @ Kt)              # Joseph form
        x1 = self.normalizer(model)(x1)
        self._count("updates", ok)
        post = BatchBelief(b.t, x1, P=P1).where(ok, BatchBelief(b.t, x, P=P))
        return BatchUpdate(post, r, S, nis, ok)


class BatchKF(BatchEKF):
    """Batched kf: the ekf's equations for a linear process (ConfigError otherwise, as kf)."""

    name = "kf"

    def predict(self, b: BatchBelief, process: Any, u, dt: float) -> BatchBelief:
        if not process.linear:
            raise ConfigError(f"filter 'kf' needs a linear process model; process {process.name!r} is not "
                              "linear (linear = False): use ekf, iekf, ukf or srukf")
        return super().predict(b, process, u, dt)


class BatchUKF(BatchFilter):
    """Batched ukf (plugins/filters/ukf.py), additive noise: all N x (2n+1) sigma points through ``f``
    and ``h`` in one call each."""

    name = "ukf"

    def __init__(self, single: Any):
        super().__init__(single)
        if getattr(single, "_augmented", False):
            raise ConfigError("the batched ukf has no augmented mode (augmented: true); run the sweep with "
                              "--engine pool")

    def sp(self, n: int):
        return self.single.sigma_points(n)

    def predict(self, b: BatchBelief, process: Any, u, dt: float) -> BatchBelief:
        if dt == 0.0:
            return b
        self._count("predicts")
        if self.single.use_linear_prediction(process):
            x1, P1 = self._linear_predict(b, process, u, dt)
            return BatchBelief(b.t + dt, x1, P=P1)
        x = b.x
        sp = self.sp(x.shape[1])
        Q = batch_Q(process, x, u, dt)                       # at the prior mean, as the ukf
        L, _ = self.factor(b.cov)
        # 000 eqs. 3-4 with the points stored component-first (n, N, 2n+1) (fusion/batch/models.py)
        Y = propagate_cf(process, sigma_points_cf(x, sp.eta, L), u, dt)
        xm = Y @ sp.Wm                                       # 000 eq. 5 (n, N)
        D = Y - xm[:, :, None]
        P1 = np.matmul((D * sp.Wc).transpose(1, 0, 2), D.transpose(1, 2, 0)) + Q   # 000 eqs. 6-7 unsquared
        return BatchBelief(b.t + dt, process.normalize(np.ascontiguousarray(xm.T)), P=sym(P1))

    def update(self, b: BatchBelief, model: Any, z, R, gate: Gate | None = None) -> BatchUpdate:
        x = b.x
        P = b.cov
        N, n = x.shape
        z = np.asarray(z, dtype=float).reshape(N, -1)
        m = z.shape[1]
        R = batch_R(R, m, N)
        L, rep = self.factor(P)
        if rep is not None:
            P = rep
        sp = self.sp(n)
        Z = model.h(sigma_points(x, sp.eta, L))              # 001 eq. 14, one call (N, 2n+1, m)
        zm = sp.Wm @ Z
        diff = _residual(model)
        dZ = diff(Z, zm[:, None, :])
        A = dZ * sp.Wc_col
        if m == 1:                                           # a range: scalars per filter, no matrices
            return self._update_scalar(b, x, P, L, dZ[:, :, 0], A[:, :, 0], R, diff(z, zm), gate, model)
        dX = sigma_deviations(sp.eta, L)
        Pzz = T(dZ) @ A + R                                  # 001 eqs. 16-17
        _, rep = self.factor(Pzz)
        if rep is not None:
            Pzz = rep
        Pxz = T(dX) @ A                                      # 001 eq. 15 (N, n, m)
        y = diff(z, zm)
        Kt = solve_spd(Pzz, T(Pxz))                          # K^T = S^-1 P_xz^T (N, m, n)
        nis = np.einsum("km,km->k", y, solve_spd(Pzz, y[:, :, None])[:, :, 0])
        ok = self.gate_mask(nis, gate, m)
        x1 = x + np.einsum("kmn,km->kn", Kt, y)             # 001 eqs. 18-19
        P1 = sym(P - Pxz @ Kt)                               # 001 eq. 20: P - K S K^T
        x1 = self.normalizer(model)(x1)
        self._count("updates", ok)
        post = BatchBelief(b.t, x1, P=P1).where(ok, BatchBelief(b.t, x, P=b.cov))
        return BatchUpdate(post, y, Pzz, nis, ok)


    def _update_scalar(self, b, x, P, L, dz, a, R, y, gate, model) -> BatchUpdate:
        """001 eqs. 15-20 for m = 1: P_zz, P_xz and K per filter as scalars and n-vectors."""
        r = R.reshape(-1)[0] if R.ndim == 2 else R[:, 0, 0]
        Pzz = (dz * a).sum(axis=1) + r                       # 001 eqs. 16-17
        Ly, rep = self.factor(Pzz[:, None, None])
        if rep is not None:
            Pzz = rep[:, 0, 0]
        Ly = Ly[:, 0, 0]
        n = x.shape[1]
        eta = self.sp(n).eta                                 # 001 eq. 15 from the points' structure:
        Pxz = np.einsum("kij,kj->ki", L, a[:, 1:n + 1] - a[:, n + 1:]) * eta
        W = Pxz / Ly[:, None]                                # L_y^-1 P_xz^T (N, n), as the ukf
        wy = y[:, 0] / Ly                                    # L_y^-1 y
        nis = wy * wy
        ok = self.gate_mask(nis, gate, 1)
        x1 = x + W * wy[:, None]                             # 001 eqs. 18-19
        P1 = P - W[:, :, None] * W[:, None, :]               # 001 eq. 20: P - W^T W (exactly symmetric)
        x1 = self.normalizer(model)(x1)
        self._count("updates", ok)
        post = BatchBelief(b.t, x1, P=P1).where(ok, BatchBelief(b.t, x, P=b.cov))
        return BatchUpdate(post, y, Pzz[:, None, None], nis, ok)


class BatchSRUKF(BatchUKF):
    """Batched srukf (plugins/filters/srukf.py) with its default ``zeroth_point: recentred``: one stacked QR a
    step, the belief holds S (N, n, n)."""

    name = "srukf"

    def __init__(self, single: Any):
        super().__init__(single)
        p = single.params
        if p.zeroth_point != "recentred":
            raise ConfigError("the batched srukf implements zeroth_point: recentred "
                              f"(got {p.zeroth_point}); run the sweep with --engine pool")

    def initial_belief(self, t: float, x, P) -> BatchBelief:
        b = super().initial_belief(t, x, P)
        L, _ = self.factor(b.P)
        return BatchBelief(b.t, b.x, S=L)

    def _S(self, b: BatchBelief) -> np.ndarray:
        return b.S if b.S is not None else self.factor(b.P)[0]

    def _transform(self, sp, D1: np.ndarray, B: np.ndarray, v0: np.ndarray) -> np.ndarray:
        """S with S S^T = w sum D1_i D1_i^T + B^T B + gamma v0 v0^T (one stacked QR, eqs. 6-7)."""
        if sp.gamma <= 0.0:
            raise ConfigError("the batched srukf needs beta >= alpha^2 (every recentred weight positive)")
        A = np.concatenate((sp.sqrt_w * D1, B, np.sqrt(sp.gamma) * v0[:, None, :]), axis=1)
        return qr_lower(A)

    def predict(self, b: BatchBelief, process: Any, u, dt: float) -> BatchBelief:
        if dt == 0.0:
            return b
        self._count("predicts")
        x = b.x
        N, n = x.shape
        Q = np.broadcast_to(batch_Q(process, x, u, dt), (N, n, n))
        S = self._S(b)
        BQ = psd_sqrt_rows(Q)
        if self.single.use_linear_prediction(process):
            F = np.broadcast_to(batch_F(process, x, u, dt), (N, n, n))
            S1 = qr_lower(np.concatenate((T(F @ S), BQ), axis=1))       # sqrt(F P F^T + Q)
            return BatchBelief(b.t + dt, process.normalize(process.f(x, _per_point(u, x), dt)), S=S1)
        sp = self.sp(n)
        Y = propagate_cf(process, sigma_points_cf(x, sp.eta, S), u, dt).transpose(1, 2, 0)   # eqs. 3-4
        Y0 = Y[:, 0]
        D1 = Y[:, 1:] - Y0[:, None, :]
        v0 = np.einsum("i,kin->kn", sp.W1, D1)                           # eq. 5 (recentred)
        xm = process.normalize(Y0 + v0)
        return BatchBelief(b.t + dt, xm, S=self._transform(sp, D1, BQ, v0))

    def update(self, b: BatchBelief, model: Any, z, R, gate: Gate | None = None) -> BatchUpdate:
        x = b.x
        S = self._S(b)
        N, n = x.shape
        z = np.asarray(z, dtype=float).reshape(N, -1)
        m = z.shape[1]
        BR = np.broadcast_to(psd_sqrt_rows(batch_R(R, m, N)), (N, m, m))
        sp = self.sp(n)
        if sp.gamma <= 0.0:
            raise ConfigError("the batched srukf needs beta >= alpha^2 (every recentred weight positive)")
        dX = sigma_deviations(sp.eta, S)
        Z = model.h(x[:, None, :] + dX)                                   # eq. 8
        diff = _residual(model)
        Z0 = Z[:, 0]
        D1 = diff(Z[:, 1:], Z0[:, None, :])
        v0 = np.einsum("i,kim->km", sp.W1, D1)
        zm = Z0 + v0                                                     # eq. 9
        y = diff(z, zm)
        c = sp.sqrt_w
        k = 2 * n
        A = np.zeros((N, k + m + 1, m + n))                              # the joint array (srukf 'joint')
        A[:, :k, :m] = c * D1
        A[:, :k, m:] = c * dX[:, 1:]
        A[:, k:k + m, :m] = BR
        A[:, -1, :m] = np.sqrt(sp.gamma) * v0
        Lj = qr_lower(A)                                                 # [[S_y, 0], [P_xz S_y^-T, S^+]]
        Sy = Lj[:, :m, :m]
        w = np.linalg.solve(Sy, y[:, :, None])[:, :, 0] if m > 1 else y / Sy[:, :, 0]
        nis = np.einsum("km,km->k", w, w)
        Syy = Sy @ T(Sy)
        ok = self.gate_mask(nis, gate, m)
        x1 = x + np.einsum("knm,km->kn", Lj[:, m:, :m], w)               # eq. 14
        S1 = Lj[:, m:, m:]
        x1 = self.normalizer(model)(x1)
        self._count("updates", ok)
        post = BatchBelief(b.t, x1, S=S1).where(ok, BatchBelief(b.t, x, S=S))
        return BatchUpdate(post, y, Syy, nis, ok)


_CLASSES = {"kf": BatchKF, "ekf": BatchEKF, "ukf": BatchUKF, "srukf": BatchSRUKF}


def batch_capable(flt: Any) -> bool:
    """Whether a wired single filter has a batched counterpart here (kf, ekf, ukf, srukf)."""
    return getattr(flt, "name", None) in _CLASSES


def make_batch_filter(flt: Any) -> BatchFilter:
    """The batched counterpart of the wired single filter ``flt`` (same parameters)."""
    cls = _CLASSES.get(getattr(flt, "name", None))
    if cls is None:
        raise ConfigError(f"filter {getattr(flt, 'name', flt)!r} has no batched version (kf, ekf, ukf, srukf have)")
    keep_heap()                            # MB-sized temporaries every step: no page faults (fusion/batch/heap.py)
    return cls(flt)
