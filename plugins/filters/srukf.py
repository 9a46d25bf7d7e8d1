"""srukf: the square-root unscented Kalman filter, paper 000 Algorithm 1 (van der Merwe & Wan)."""
from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field

from fusion.api import Belief, ProcessModel

from .base import as_covariance, linearised_predict
from .linalg import cholupdate, psd_sqrt_rows, qr_lower, qr_lower_scaled, recover_factor, solve_lower
from .sigma_point_filter import SigmaPointFilter
from .sigma_points import SigmaPoints, UnscentedParams


class SquareRootUnscentedKalmanFilter(SigmaPointFilter):
    r"""Square-root UKF (paper 000 Algorithm 1, additive noise): the belief holds the lower Cholesky
    factor S (P = S S^T, ``Belief.P`` is None); P is never formed nor factorised.

    Prediction (c = sqrt(W^i), i >= 1; B_Q a row square root of Q, B_Q^T B_Q = Q)::

        chi = [x, x + eta S_i, x - eta S_i]                               (eq. 3)
        Y_i = f(chi_i, u, dt)     (one call on the (2n+1, n) array)       (eq. 4)
        x^- = sum W_m^i Y_i                                               (eq. 5)
        S^- = qr{[c (Y_1:2n - x^-); B_Q]}                                 (eq. 6)
        S^- = cholupdate{S^-, Y_0 - x^-, W_c^0}  (a downdate when W_c^0 < 0)    (eq. 7)

    or, for a linear process (``linear_prediction``), ``x^- = f(x)``, ``S^- = qr{[(F S)^T; B_Q]}``.

    Update, with sigma points redrawn from (x^-, S^-) as in the ukf (so srukf == ukf to rounding)::

        Z_i = h(chi_i),  z^ = sum W_m^i Z_i                               (eqs. 8-9)
        S_y = qr{[c (Z_1:2n - z^); B_R]},  S_y = cholupdate{S_y, Z_0 - z^, W_c^0}   (eqs. 10-11)
        P_xz = sum W_c^i (chi_i - x^-)(Z_i - z^)^T                         (eq. 12)
        K = (P_xz / S_y^T) / S_y     (two triangular solves)              (eq. 13)
        x^+ = x^- + K (z - z^)                                            (eq. 14, as corrected)
        U = K S_y,  S^+ = cholupdate{S^-, U, -1}                           (eqs. 15-16)

    Eqs. 10-16 are computed in the "array form" of square-root filters: one QR of the stacked deviations
    of measurement and state, then one cholupdate of the joint factor for the zeroth point::

        L = qr{[c (Z_1:2n - z^), c (chi_1:2n - x^-); B_R, 0]},  L = cholupdate{L, [Z_0 - z^; 0], W_c^0}
        L = [[S_y, 0], [P_xz S_y^-T, S^+]]

    since L L^T is the joint covariance [[P_zz, P_zx], [P_xz, P^-]] and its Cholesky factor has those
    blocks (block Cholesky: S^+ S^+^T = P^- - P_xz P_zz^-1 P_zx = P^- - K S K^T). The gain is applied by
    one triangular solve: ``K y = (P_xz S_y^-T)(S_y^-1 y)``. The same numbers as eqs. 10-16 written out
    (QR and cholupdate for S_y, m rank-1 downdates for S^+), at a third of the time (benchmarks/README.md).

    ``zeroth_point``: ``cholupdate`` is eqs. 5-7 and 9-11 as written (QR of points 1..2n about the mean,
    then a rank-1 update, or a downdate when W_c^0 < 0, for the zeroth point). ``recentred`` (default)
    forms the same covariances about the zeroth point instead of the mean, an identity for weights
    summing to 1::

        sum W_c^i (Y_i - y^)(Y_i - y^)^T = sum_{i>=1} W^i (Y_i - Y_0)(Y_i - Y_0)^T
                                          + (beta - alpha^2) (y^ - Y_0)(y^ - Y_0)^T,
        y^ = Y_0 + sum_{i>=1} W^i (Y_i - Y_0)

    so for beta >= alpha^2 (beta = 2: always) every weight is positive and the zeroth point joins the QR
    as one more row: no downdate, one QR per step, ~25% faster, and never a negative weight times a
    large one (at alpha = 1e-3, W_c^0 ~ -1e6); both agree with the ukf to 1e-8 (tests) and with an
    extended-precision reference to the same ~1e-8 at alpha = 1e-3, where the loss comes from the
    sigma points themselves (differences of h over steps of alpha sigma; benchmarks/README.md).
    A negative beta - alpha^2 falls back on the cholupdate downdate.

    The rank-1 cholupdate is vectorised (linalg.cholupdate). A failed downdate (loss of positive
    definiteness) is detected, recovered by re-factorising the symmetrised covariance with its eigenvalues
    clipped (never NaN) and reported as a ``not_positive_definite`` event on the result (the predicted
    belief's ``events``, the update's ``UpdateResult.events``). The filter keeps no state or cache.
    """

    name = "srukf"
    square_root = True

    class Params(UnscentedParams):
        """Scaled unscented transform parameters and the square-root variant."""

        zeroth_point: Literal["recentred", "cholupdate"] = Field(
            "recentred", description="recentred: covariances about the zeroth point, every weight "
                                     "positive (one QR); cholupdate: eqs. 6-7 as written (QR, then a "
                                     "rank-1 update/downdate with W_c^0)")

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        self._recentred = self.params.zeroth_point == "recentred"

    # ------------------------------------------------------------------ helpers
    def initial_belief(self, t: float, x: np.ndarray, P: np.ndarray) -> Belief:
        b = super().initial_belief(t, x, P)
        L, _, event = self.factor(b.P, t, "initial covariance")
        return Belief(b.t, b.x, S=L, events=(event,) if event is not None else ())

    def sqrt_of(self, belief: Belief, events: list) -> np.ndarray:
        """S of a belief (the Cholesky factor of P for a covariance belief; a repair goes to ``events``)."""
        if belief.S is not None:
            return belief.S
        L, _, event = self.factor(belief.P, belief.t, "srukf")
        if event is not None:
            events.append(event)
        return L

    def rank1(self, L: np.ndarray, v: np.ndarray, weight: float, t: float, where: str, events: list) -> np.ndarray:
        """cholupdate{L, v, weight} with recovery of a failed downdate (its event appended to ``events``)."""
        L1, ok = cholupdate(L, v, weight)
        if ok:
            return L1
        events.append(self.event(t, "not_positive_definite",
                                 f"{where}: cholupdate with weight {weight:.3g} failed, repaired"))
        return recover_factor(L @ L.T + weight * np.outer(v, v))

    def deviations(self, sp: SigmaPoints, Y: np.ndarray, diff):
        """Mean of the transformed points Y (2n+1, m) and the deviations for the square-root
        transform: ``(mean, D1, v0, w0)`` with covariance ``W sum D1_i D1_i^T + w0 v0 v0^T``: D1 (2n, m)
        the deviations of points 1..2n (from the mean, or from Y_0 when recentred), v0 and w0 the
        zeroth-point term and its weight (eqs. 5, 9)."""
        if not self._recentred:
            mean = sp.Wm @ Y
            D = diff(Y, mean)
            return mean, D[1:], D[0], sp.Wc[0]
        Y0 = Y[0]
        D1 = diff(Y[1:], Y0)
        v0 = sp.W1 @ D1                        # sum_{i>=1} W^i (Y_i - Y_0) = y^ - Y_0
        return Y0 + v0, D1, v0, sp.gamma

    def sqrt_transform(self, sp: SigmaPoints, D1: np.ndarray, B: np.ndarray, v0: np.ndarray, w0: float,
                       t: float, where: str, events: list) -> np.ndarray:
        """S with S S^T = W sum D1_i D1_i^T + B^T B + w0 v0 v0^T: one QR (eqs. 6, 10) and, for a
        negative w0, one rank-1 downdate (eqs. 7, 11); a positive w0 joins the QR as a row."""
        if w0 > 0.0:
            # stacked as columns of the transpose, so that A comes out Fortran-ordered for LAPACK
            return qr_lower(np.concatenate((sp.sqrt_w * D1.T, B.T, math.sqrt(w0) * v0[:, None]), axis=1).T,
                            overwrite=True)
        S = qr_lower(np.concatenate((sp.sqrt_w * D1.T, B.T), axis=1).T, overwrite=True)
        return self.rank1(S, v0, w0, t, where, events) if w0 < 0.0 else S

    # ------------------------------------------------------------------ predict
    def predict(self, belief: Belief, process: ProcessModel, u: np.ndarray | None, dt: float) -> Belief:
        if dt == 0.0:
            return belief
        if self.use_linear_prediction(process):
            events: list = []
            S = self.sqrt_of(belief, events)
            x1, F, Q = linearised_predict(belief, process, u, dt)
            BQ = psd_sqrt_rows(Q)
            S1 = qr_lower(np.concatenate((F @ S, BQ.T), axis=1).T, overwrite=True)   # sqrt(F P F^T + Q)
            return Belief(belief.t + dt, x1, S=S1, events=tuple(events))
        Q = process.Q(belief.x, u, dt)
        return self.sigma_predict(belief, process, lambda X: process.f(X, u, dt), lambda x0, x1: Q, dt)

    def sigma_predict(self, belief: Belief, process: ProcessModel, propagate, noise, dt: float) -> Belief:
        x = belief.x
        events: list = []
        S = self.sqrt_of(belief, events)
        sp = self.sigma_points(x.shape[0])
        dX = sp.E @ S.T
        Y = propagate(x + dX)                                       # eqs. 3-4, one call
        xm, D1, v0, w0 = self.deviations(sp, Y, np.subtract)        # eq. 5
        xm = process.normalize(xm)
        BQ = psd_sqrt_rows(noise(x, xm))
        S1 = self.sqrt_transform(sp, D1, BQ, v0, w0, belief.t, "srukf predict", events)  # eqs. 6-7
        return Belief(belief.t + dt, xm, S=S1, events=tuple(events))

    # ------------------------------------------------------------------ update (SigmaPointFilter.update)
    def prior_factor(self, belief: Belief, events: list) -> tuple[np.ndarray, np.ndarray]:
        S = belief.S if belief.S is not None else self.sqrt_of(belief, events)
        return S, S

    def innovation(self, sp, dX, Z, diff, z, R, prior, t, events):
        """S_y, P_xz S_y^-T and S^+ as the blocks of one QR (eqs. 9-16 in array form, the class docstring)."""
        m = Z.shape[1]
        n = dX.shape[1]
        BR = psd_sqrt_rows(as_covariance(R, m))
        if self._recentred:                                          # eq. 9 (deviations(), inline)
            Z0 = Z[0]
            D1 = diff(Z[1:], Z0)
            V = sp.W1_rows @ D1
            v0 = V[0]
            zm, w0 = Z0 + v0, sp.gamma
        else:
            zm, D1, v0, w0 = self.deviations(sp, Z, diff)
            V = None
        k = 2 * n
        c = sp.sqrt_w
        # the rows [c D1, c dX1; B_R, 0; sqrt(w0) v0] divided by c (plain copies into the Fortran-ordered A, no
        # strided products); c goes onto the triangle in qr_lower_scaled
        A = np.zeros((k + m + (w0 > 0.0), m + n), order="F")
        A[:k, :m] = D1
        A[:k, m:] = dX[1:]
        A[k:k + m, :m] = BR / c
        if w0 > 0.0:
            A[-1, :m] = V[1] if V is not None else v0 * (math.sqrt(w0) / c)
        J = qr_lower_scaled(A, c)                                    # eqs. 10, 12-13, 15-16 at once
        if w0 < 0.0:
            J = self.rank1(J, np.concatenate((v0, np.zeros(n))), w0, t, "srukf update", events)  # eq. 11
        Sy = J[:m, :m]
        y = diff(z, zm)
        # eq. 14: K y = (P_xz S_y^-T) S_y^-1 y, G^T = P_xz S_y^-T the joint factor's lower-left block
        return y, Sy @ Sy.T, solve_lower(Sy, y), J[m:, :m].T, J[m:, m:]
