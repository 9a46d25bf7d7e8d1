"""srukf: the square-root unscented Kalman filter, paper 000 Algorithm 1 (van der Merwe & Wan)."""
from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field

from fusion.api import Belief, Gate, MeasurementModel, ProcessModel, UpdateResult

from .base import as_covariance
from .jacobian import process_jacobian
from .linalg import cholupdate, psd_sqrt_rows, qr_lower, recover_factor, solve_lower, symmetrise
from .sigma_points import SigmaPoints, UnscentedParams
from .ukf import SigmaPointFilter


def _subtract(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a - b


class SquareRootUnscentedKalmanFilter(SigmaPointFilter):
    r"""Square-root UKF (paper 000 Algorithm 1, additive noise): the belief holds the lower Cholesky
    factor S (P = S S^T, ``Belief.P`` is None) and P is never formed or factorised.

    Prediction (c = sqrt(W_c^1) = sqrt(W^i), B_Q a row square root of Q: B_Q^T B_Q = Q)::

        chi = [x, x + eta S_i, x - eta S_i]                               (eq. 3)
        Y_i = f(chi_i, u, dt)     (one call on the (2n+1, n) array)       (eq. 4)
        x^- = sum W_m^i Y_i                                               (eq. 5)
        S^- = qr{[c (Y_1:2n - x^-); B_Q]}                                 (eq. 6)
        S^- = cholupdate{S^-, Y_0 - x^-, W_c^0}    (a downdate when W_c^0 < 0)   (eq. 7)

    or, for a linear process (``linear_prediction``), ``x^- = f(x)``, ``S^- = qr{[(F S)^T; B_Q]}``.

    Update, sigma points redrawn from (x^-, S^-) as in the ukf (so srukf == ukf to rounding)::

        Z_i = h(chi_i),  z^ = sum W_m^i Z_i                               (eqs. 8-9)
        S_y = qr{[c (Z_1:2n - z^); B_R]},  S_y = cholupdate{S_y, Z_0 - z^, W_c^0}   (eqs. 10-11)
        P_xz = sum W_c^i (chi_i - x^-)(Z_i - z^)^T                         (eq. 12)
        K = (P_xz / S_y^T) / S_y     (two triangular solves)              (eq. 13)
        x^+ = x^- + K (z - z^)                                            (eq. 14, as corrected)
        U = K S_y,  S^+ = cholupdate{S^-, U, -1}                           (eqs. 15-16)

    ``covariance_update: downdate`` does eqs. 15-16 literally (m rank-1 downdates); the default
    ``qr`` gets the same S^+ from one QR of a stacked matrix (Joseph-like, every term positive)::

        S^+ = qr{[c ((chi_1:2n - x^-) - K (Z_1:2n - z^)); B_R K^T]},
        S^+ = cholupdate{S^+, K (Z_0 - z^), W_c^0}

    since ``sum W_c (dx - K dz)(dx - K dz)^T + K R K^T = P - K S K^T``.

    ``zeroth_point``: ``cholupdate`` (default) is Algorithm 1 as written. ``recentred`` forms every
    covariance about the zeroth point instead of the mean, an exact identity for weights summing to 1::

        sum W_c^i (Y_i - y^)(Y_i - y^)^T = sum_{i>=1} W^i (Y_i - Y_0)(Y_i - Y_0)^T
                                          + (beta - alpha^2) (y^ - Y_0)(y^ - Y_0)^T,
        y^ = Y_0 + sum_{i>=1} W^i (Y_i - Y_0)

    so all weights are positive for beta >= alpha^2 (no downdate, one QR), and the ~-1e6 zeroth
    weight at alpha = 1e-3 never multiplies anything: it keeps ~12 digits where the textbook form keeps
    ~6 (benchmarks/README.md).

    The rank-1 cholupdate is vectorised (linalg.cholupdate). A failed downdate (loss of positive
    definiteness) is detected, counted in ``counters['not_positive_definite']``, reported in ``events``
    and recovered by re-factorising the symmetrised covariance with its eigenvalues clipped: never NaN.
    """

    name = "srukf"

    class Params(UnscentedParams):
        """Scaled unscented transform parameters and the square-root variant."""

        zeroth_point: Literal["cholupdate", "recentred"] = Field(
            "cholupdate", description="cholupdate: Algorithm 1 (rank-1 update/downdate with W_c^0); "
                                      "recentred: covariances about the zeroth point, no downdate")
        covariance_update: Literal["qr", "downdate"] = Field(
            "qr", description="qr: one QR of a stacked matrix; downdate: eqs. 15-16, m rank-1 downdates")

    # ------------------------------------------------------------------ helpers
    def initial_belief(self, t: float, x: np.ndarray, P: np.ndarray) -> Belief:
        b = super().initial_belief(t, x, P)
        return Belief(b.t, b.x, S=self.factor(b.P, t, "initial covariance"))

    def sqrt_of(self, belief: Belief) -> np.ndarray:
        """S of a belief (the Cholesky factor of P for a covariance belief)."""
        if belief.S is not None:
            return belief.S
        return self.factor(belief.P, belief.t, "srukf")

    def rank1(self, L: np.ndarray, v: np.ndarray, weight: float, t: float, where: str) -> np.ndarray:
        """cholupdate{L, v, weight} with recovery of a failed downdate."""
        L1, ok = cholupdate(L, v, weight)
        if ok:
            return L1
        self.report(t, "not_positive_definite", f"{where}: cholupdate with weight {weight:.3g} failed, repaired")
        return recover_factor(L @ L.T + weight * np.outer(v, v))

    def sqrt_transform(self, sp: SigmaPoints, Y: np.ndarray, B: np.ndarray, diff, t: float, where: str):
        """Square-root unscented transform of the transformed points Y (2n+1, m) plus noise B^T B.

        Returns ``(mean, S, D1, v0, w0)`` with ``S S^T = W sum D1_i D1_i^T + B^T B + w0 v0 v0^T``: D1
        (2n, m) the deviations of points 1..2n (from the mean, or from Y_0 when recentred), v0 and w0
        the zeroth-point term and its weight (eqs. 5-7 / 9-11)."""
        if self.params.zeroth_point == "cholupdate":
            mean = sp.Wm @ Y
            D = diff(Y, mean)
            D1, v0, w0 = D[1:], D[0], sp.Wc[0]
        else:
            D1 = diff(Y[1:], Y[0])
            v0 = sp.w * D1.sum(axis=0)
            mean = Y[0] + v0
            w0 = sp.gamma
        S = qr_lower(self.stack(sp.sqrt_w * D1, B, v0, w0))
        if w0 < 0.0:
            S = self.rank1(S, v0, w0, t, where)
        return mean, S, D1, v0, w0

    @staticmethod
    def stack(A: np.ndarray, B: np.ndarray, v0: np.ndarray, w0: float) -> np.ndarray:
        """[A; B] plus the row sqrt(w0) v0 when w0 > 0 (a positive zeroth weight joins the QR)."""
        if w0 > 0.0:
            return np.concatenate((A, B, math.sqrt(w0) * v0[None]))
        return np.concatenate((A, B))

    # ------------------------------------------------------------------ predict
    def predict(self, belief: Belief, process: ProcessModel, u: np.ndarray | None, dt: float) -> Belief:
        self.process = process
        if dt == 0.0:
            return belief
        x = belief.x
        S = self.sqrt_of(belief)
        BQ = psd_sqrt_rows(process.Q(x, u, dt))
        self.counters["predicts"] += 1
        if self.use_linear_prediction(process):
            F = process_jacobian(process, x, u, dt)
            S1 = qr_lower(np.concatenate(((F @ S).T, BQ)))      # F P F^T + Q, square root
            return Belief(belief.t + dt, process.normalize(process.f(x, u, dt)), S=S1)
        sp = self.sigma_points(x.shape[0])
        Y = process.f(x + sp.E @ S.T, u, dt)                     # eqs. 3-4, one call
        xm, S1, _, _, _ = self.sqrt_transform(sp, Y, BQ, _subtract, belief.t, "srukf predict")  # eqs. 5-7
        return Belief(belief.t + dt, process.normalize(xm), S=S1)

    # ------------------------------------------------------------------ update
    def update(self, belief: Belief, model: MeasurementModel, z: np.ndarray, R: np.ndarray,
               gate: Gate | None = None) -> UpdateResult:
        x = belief.x
        S = self.sqrt_of(belief)
        z = np.asarray(z, dtype=float).reshape(-1)
        m = z.shape[0]
        BR = psd_sqrt_rows(as_covariance(R, m))
        sp = self.sigma_points(x.shape[0])
        dX = sp.E @ S.T
        Z = model.h(x + dX)                                       # eq. 8, one call
        zm, Sy, D1, v0, w0 = self.sqrt_transform(sp, Z, BR, model.residual, belief.t,
                                                 "srukf innovation")        # eqs. 9-11
        dX1 = dX[1:]
        Pxz = (sp.w * dX1.T) @ D1                                 # eq. 12 (chi_0 - x^- = 0)
        y = model.residual(z, zm)
        w = solve_lower(Sy, y)
        nis = float(w @ w)
        Syy = symmetrise(Sy @ Sy.T)
        out = self.rejected(belief, y, Syy, nis, gate, m)
        if out is not None:
            return out
        W = solve_lower(Sy, Pxz.T)                                # S_y^-1 P_xz^T
        x1 = x + w @ W                                            # eq. 14: K y = W^T S_y^-1 y
        Kt = solve_lower(Sy, W, trans=1)                          # eq. 13: K^T = S_y^-T S_y^-1 P_xz^T
        if self.params.covariance_update == "qr":
            A = self.stack(sp.sqrt_w * (dX1 - D1 @ Kt), BR @ Kt, v0 @ Kt, w0)
            S1 = qr_lower(A)
            if w0 < 0.0:
                S1 = self.rank1(S1, v0 @ Kt, w0, belief.t, "srukf update")
        else:
            U = Kt.T @ Sy                                         # eq. 15
            S1 = S
            for j in range(m):                                    # eq. 16: m downdates (m columns, not points)
                S1 = self.rank1(S1, U[:, j], -1.0, belief.t, "srukf update")
        self.counters["updates"] += 1
        return UpdateResult(Belief(belief.t, self.normalize(x1), S=S1), y, Syy, nis, True)
