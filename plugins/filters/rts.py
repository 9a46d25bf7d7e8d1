r"""Rauch-Tung-Striebel smoothing for the five filters: the forward terms of each transition and the
backward step, kept out of the filters themselves (their outputs stay as they are).

A transition k -> k+1 (one ``predict``, or one ``predict_inputs`` run of input samples) from the
filtered belief (x_k, P_k) to the predicted one (x^-_{k+1}, P^-_{k+1}) has the cross-covariance
``C_k = Cov(x_k, x_{k+1})`` and the smoother gain ``G_k = C_k (P^-_{k+1})^-1``:

* linear / linearised prediction (kf, ekf, iekf, and ukf/srukf with ``linear_prediction``): the filters'
  own ``F = df/dx`` at the filtered mean (the EKF's linearisation point), ``C_k = P_k F^T``;
* sigma points (ukf; Saerkkae 2008, "Unscented Rauch-Tung-Striebel smoother", eqs. 12-13): the same
  points and weights as the prediction, ``C_k = sum W_c^i (chi_i - x_k)(Y_i - x^-_{k+1})^T``;
* square root (srukf): one QR of the stacked deviations of (x_{k+1}, x_k) (the joint "array form")::

      L = qr{[sqrt(W) (Y_1:2n - Y_0), sqrt(W) (chi_1:2n - x); B_Q, 0; sqrt(gamma) (y^ - Y_0), 0]}
        = [[S^-_{k+1}, 0], [C_k S^-_{k+1}^-T, S_c]],   G_k = (C_k S^-_{k+1}^-T) S^-_{k+1}^-1

  with ``S_c S_c^T = P_k - G_k P^-_{k+1} G_k^T`` (the covariance of x_k given x_{k+1}); P is never formed.

A run of samples predicted one by one composes exactly: with no update in between, the gains multiply,
``G = G_1 G_2 ... G_m``, and ``S_c = qr{[S_c1^T; (G_1 S_c2)^T; ...]}``; the EKF's chain is
``C = P_k (F_m ... F_1)^T``. Backward step (Rauch, Tung & Striebel 1965; FilterPy's ``rts_smoother``)::

    x^s_k = x_k + G_k (x^s_{k+1} - x^-_{k+1})                         (normalised: quaternion blocks)
    P^s_k = P_k + G_k (P^s_{k+1} - P^-_{k+1}) G_k^T                   (covariance form)
    S^s_k = qr{[S_c^T; (G_k S^s_{k+1})^T]}                            (square-root form)

``G`` is obtained by Cholesky solves with P^- (or triangular solves with S^-), never an inverse.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fusion.api import Belief, ConfigError, IntegratesInputRuns, ProcessModel, has

from .base import KalmanBase, covariance_of
from .jacobian import process_jacobian
from .linalg import cho_solve_lower, cholupdate, psd_sqrt_rows, qr_lower, recover_factor, robust_cholesky, \
    solve_lower, symmetrise
from .srukf import SquareRootUnscentedKalmanFilter
from .sigma_point_filter import SigmaPointFilter

__all__ = ["Step", "RtsBackend", "backend_for", "rts_step", "rts_step_sqrt"]


@dataclass
class Step:
    """What the backward pass needs of one transition: the gain ``G`` (n, n), the filtered covariance
    ``A`` = P_k (covariance form) or the conditional factor S_c (square-root form), and the predicted
    belief ``b1`` (its mean x^-_{k+1}; its P^-_{k+1} in covariance form)."""

    G: np.ndarray
    A: np.ndarray
    b1: Belief


def _gain(C: np.ndarray, P1: np.ndarray) -> np.ndarray:
    """G = C P1^-1 by a Cholesky solve (P1 symmetric): G^T = P1^-1 C^T."""
    L, _ = robust_cholesky(P1)
    return cho_solve_lower(L, np.ascontiguousarray(C.T)).T


class _JacobianMemo:
    """The process model as the filter sees it, remembering the last analytic Jacobian it gave the filter
    (so the smoother does not compute F twice; the filter gets the model's own numbers)."""

    def __init__(self, process: ProcessModel):
        self.__dict__.update(_process=process, x=None, F=None)

    def __getattr__(self, name: str):
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.__dict__["_process"], name)

    def jacobian(self, x, u, dt):
        F = self._process.jacobian(x, u, dt)
        self.__dict__.update(x=x, F=F)
        return F

    def F_at(self, x, u, dt) -> np.ndarray:
        """F at x: the one the filter just used when it asked at this very x, else computed."""
        if self.x is x and self.F is not None:
            return self.F
        return process_jacobian(self._process, x, u, dt)


class RtsBackend:
    """Forward terms of the smoother for one filter (``flt``, the filter the scheduler runs). ``sqrt``:
    the belief and the smoothed belief are square-root (``Belief.S``)."""

    sqrt = False

    def __init__(self, flt: KalmanBase):
        self.flt = flt
        self.mode = self._mode(flt)
        self._memo: _JacobianMemo | None = None

    def memo(self, process: ProcessModel) -> _JacobianMemo:
        m = self._memo
        if m is None or m._process is not process:
            m = self._memo = _JacobianMemo(process)
        return m

    @staticmethod
    def _mode(flt) -> str:
        if isinstance(flt, SigmaPointFilter):
            if getattr(flt, "_augmented", False):
                raise ConfigError(f"smoothing: filter {flt.name!r} with 'augmented: true' is not supported; "
                                  "use the additive-noise ukf (augmented: false)")
            return "sigma"
        return "linear"

    # ------------------------------------------------------------------ one predict
    def predict(self, b0: Belief, process: ProcessModel, u, dt: float) -> tuple[Belief, Step | None]:
        """``flt.predict`` and its transition terms (None when the filter did not move the belief)."""
        flt = self.flt
        if self.mode == "linear" or flt.use_linear_prediction(process):
            memo = self.memo(process)
            b1 = flt.predict(b0, memo, u, dt)
            if b1 is b0:
                return b1, None
            F = memo.F_at(b0.x, u, dt)
            return b1, self.linear_step(b0, F, b1, process.Q(b0.x, u, dt))
        b1 = flt.predict(b0, process, u, dt)
        if b1 is b0:
            return b1, None
        return b1, self.sigma_step(b0, lambda X: process.f(X, u, dt), process.Q(b0.x, u, dt), b1)

    def predict_inputs(self, b0: Belief, process: ProcessModel, us: np.ndarray, dts: np.ndarray
                       ) -> tuple[Belief, Step | None]:
        """``flt.predict_inputs`` and the terms of the whole run: one sigma-point step when the filter
        batches it (``SigmaPointFilter.batches_inputs``), else the composition of the per-sample steps
        (the filter's own per-sample path, so the recorded terms are those of the forward pass)."""
        flt = self.flt
        batched = self.mode == "sigma" and flt.batches_inputs(process, len(dts))
        if not batched and not self.sqrt and (self.mode == "linear" or flt.use_linear_prediction(process)):
            # the EKF chain: C = P_k (F_m ... F_1)^T, one gain for the run
            b, Phi = b0, None
            memo = self.memo(process)
            for u, dt in zip(us, dts):
                x = b.x
                b1 = flt.predict(b, memo, u, float(dt))
                if b1 is not b:
                    F = memo.F_at(x, u, float(dt))
                    Phi = F if Phi is None else F @ Phi
                b = b1
            if Phi is None:
                return b, None
            P0 = covariance_of(b0)
            return b, Step(_gain(P0 @ Phi.T, covariance_of(b)), P0, b)
        if not batched:
            step = None
            b = b0
            for u, dt in zip(us, dts):
                b, s = self.predict(b, process, u, float(dt))
                if s is not None:
                    step = s if step is None else self.compose(step, s)
            return b, step
        us = np.asarray(us, dtype=float)
        dts = np.asarray(dts, dtype=float)
        b1 = flt.predict_inputs(b0, process, us, dts)
        f_inputs = process.f_inputs if has(process, IntegratesInputRuns) else None

        def propagate(X):
            if f_inputs is not None:
                return f_inputs(X, us, dts)
            for u, dt in zip(us, dts):
                X = process.f(X, u, float(dt))
            return X

        return b1, self.sigma_step(b0, propagate, process.Q_inputs(b0.x, b1.x, us, dts), b1)

    # ------------------------------------------------------------------ covariance form
    def linear_step(self, b0: Belief, F: np.ndarray, b1: Belief, Q: np.ndarray) -> Step:
        P0 = covariance_of(b0)
        return Step(_gain(P0 @ F.T, covariance_of(b1)), P0, b1)

    def sigma_step(self, b0: Belief, propagate, Q: np.ndarray, b1: Belief) -> Step:
        """C = sum W_c^i (chi_i - x)(Y_i - y^)^T from the prediction's own points (Saerkkae 2008 eq. 12)."""
        sp = self.flt.sigma_points(b0.x.shape[0])
        P0 = covariance_of(b0)
        S, _ = robust_cholesky(P0)
        dX = sp.E @ S.T
        Y = propagate(b0.x + dX)
        D = Y - sp.Wm @ Y
        C = (dX.T * sp.Wc) @ D
        return Step(_gain(C, covariance_of(b1)), P0, b1)

    def compose(self, a: Step, b: Step) -> Step:
        """Two transitions with no update between them as one: G = G_a G_b (module docstring)."""
        return Step(a.G @ b.G, a.A, b.b1)

    def broken(self, b: Belief) -> Step:
        """The terms of a break in the chain (a reset, a re-initialised belief): G = 0, so the smoothed
        belief before the break is the filtered one."""
        n = b.x.shape[0]
        return Step(np.zeros((n, n)), covariance_of(b), b)

    def final(self, b: Belief) -> np.ndarray:
        """The covariance (or factor) the backward pass starts from at the last node."""
        return covariance_of(b)


class SqrtRtsBackend(RtsBackend):
    """The square-root smoother of the srukf: every covariance is a lower Cholesky factor."""

    sqrt = True

    @staticmethod
    def _sqrt(b: Belief) -> np.ndarray:
        return b.S if b.S is not None else robust_cholesky(b.cov)[0]

    def _joint(self, Dy: np.ndarray, Dx: np.ndarray, BQ: np.ndarray, extra=None) -> Step:
        """Split the joint factor of the rows ``[Dy, Dx; BQ, 0]`` (plus a rank-1 term ``extra = (v,
        weight)`` on the x_{k+1} part) into S^-, C S^-^T and S_c; returns (G, S_c)."""
        n = Dx.shape[1]
        A = np.zeros((Dy.shape[0] + BQ.shape[0], 2 * n))
        A[:Dy.shape[0], :n] = Dy
        A[:Dy.shape[0], n:] = Dx
        A[Dy.shape[0]:, :n] = BQ
        L = qr_lower(A)
        if extra is not None:
            v, w = extra
            L1, ok = cholupdate(L, np.concatenate([v, np.zeros(n)]), w)
            L = L1 if ok else recover_factor(L @ L.T + w * np.outer(np.r_[v, np.zeros(n)], np.r_[v, np.zeros(n)]))
        S1, M, Sc = L[:n, :n], L[n:, :n], L[n:, n:]
        G = solve_lower(S1, np.ascontiguousarray(M.T), trans=1).T   # G = M S1^-1
        return G, Sc

    def linear_step(self, b0: Belief, F: np.ndarray, b1: Belief, Q: np.ndarray) -> Step:
        S0 = self._sqrt(b0)
        G, Sc = self._joint((F @ S0).T, S0.T, psd_sqrt_rows(Q))
        return Step(G, Sc, b1)

    def sigma_step(self, b0: Belief, propagate, Q: np.ndarray, b1: Belief) -> Step:
        sp = self.flt.sigma_points(b0.x.shape[0])
        S0 = self._sqrt(b0)
        dX = sp.E @ S0.T
        Y = propagate(b0.x + dX)
        D1 = Y[1:] - Y[0]                        # about the zeroth point (srukf ``recentred``)
        v0 = sp.W1 @ D1                          # y^ - Y_0
        c = sp.sqrt_w
        BQ = psd_sqrt_rows(Q)
        if sp.gamma > 0.0:
            Dy = np.vstack([c * D1, math.sqrt(sp.gamma) * v0[None, :]])
            Dx = np.vstack([c * dX[1:], np.zeros((1, dX.shape[1]))])
            G, Sc = self._joint(Dy, Dx, BQ)
        else:
            G, Sc = self._joint(c * D1, c * dX[1:], BQ, (v0, sp.gamma))
        return Step(G, Sc, b1)

    def compose(self, a: Step, b: Step) -> Step:
        """S_c = qr{[S_ca^T; (G_a S_cb)^T]}, G = G_a G_b."""
        Sc = qr_lower(np.vstack([a.A.T, (a.G @ b.A).T]))
        return Step(a.G @ b.G, Sc, b.b1)

    def broken(self, b: Belief) -> Step:
        n = b.x.shape[0]
        return Step(np.zeros((n, n)), self._sqrt(b), b)

    def final(self, b: Belief) -> np.ndarray:
        return self._sqrt(b)


def backend_for(flt) -> RtsBackend:
    """The smoother backend of a filter: its own ``rts_backend()`` when it declares one (a third-party
    filter's capability), the square-root one for the srukf, the covariance one for the other built-ins.
    ConfigError for a filter that has neither."""
    from fusion.smoothing.protocol import SmoothableFilter

    if isinstance(flt, SmoothableFilter):
        return flt.rts_backend()
    if isinstance(flt, SquareRootUnscentedKalmanFilter):
        return SqrtRtsBackend(flt)
    if isinstance(flt, KalmanBase):
        return RtsBackend(flt)
    raise ConfigError(f"smoothing: filter {getattr(flt, 'name', flt)!r} has no Rauch-Tung-Striebel smoother "
                      "(built in for kf, ekf, iekf, ukf and srukf; a plugin filter can declare rts_backend())")


# ---------------------------------------------------------------------- backward steps
def rts_step(x: np.ndarray, P: np.ndarray, G: np.ndarray, x1: np.ndarray, P1: np.ndarray, xs1: np.ndarray,
             Ps1: np.ndarray, diff=np.subtract) -> tuple[np.ndarray, np.ndarray]:
    """One backward step in covariance form: ``(x^s_k, P^s_k)`` (not normalised)."""
    xs = x + G @ diff(xs1, x1)
    Ps = symmetrise(P + G @ (Ps1 - P1) @ G.T)
    return xs, Ps


def rts_step_sqrt(x: np.ndarray, Sc: np.ndarray, G: np.ndarray, x1: np.ndarray, xs1: np.ndarray,
                  Ss1: np.ndarray, diff=np.subtract) -> tuple[np.ndarray, np.ndarray]:
    """One backward step in square-root form: ``(x^s_k, S^s_k)``, S^s = qr{[S_c^T; (G S^s_{k+1})^T]}."""
    xs = x + G @ diff(xs1, x1)
    Ss = qr_lower(np.vstack([Sc.T, (G @ Ss1).T]))
    return xs, Ss
