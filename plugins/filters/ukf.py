"""ukf: the unscented Kalman filter (papers 000 and 001)."""
from __future__ import annotations

import numpy as np
from pydantic import Field

from scipy.linalg import blas
from fusion.api import (Belief, MeasurementModel, NonAdditiveMeasurementNoise, NonAdditiveProcessNoise,
                        ProcessModel, has)

from .base import as_covariance, covariance_of, linear_predict, linearised_predict, residual_of
from .linalg import psd_sqrt_rows, symmetrise
from .sigma_point_filter import SigmaPointFilter
from .sigma_points import UnscentedParams

__all__ = ["UnscentedKalmanFilter", "SigmaPointFilter"]   # SigmaPointFilter: import shim, now in sigma_point_filter.py

_dtrsm = blas.dtrsm


class UnscentedKalmanFilter(SigmaPointFilter):
    r"""Unscented Kalman filter, additive noise (paper 001 eqs. 7-20; paper 000 Algorithm 1 in
    covariance form), with an augmented-state option.

    Prediction, sigma points (``linear_prediction: never``, or ``auto`` with a non-linear process)::

        chi = [x, x + eta S_i, x - eta S_i],  S = chol(P)            (000 eq. 3, 001 eq. 11)
        Y_i = f(chi_i, u, dt)   (one call on the whole (2n+1, n) array) (000 eq. 4)
        x^- = sum W_m^i Y_i                                          (000 eq. 5)
        P^- = sum W_c^i (Y_i - x^-)(Y_i - x^-)^T + Q                  (000 eq. 6-7 unsquared)

    or, for a linear process (``auto``) or on request (``always``), ``x^- = f(x)``,
    ``P^- = F P F^T + Q`` (001 eqs. 9-10; identical for affine f, and cheaper).

    Update, with sigma points redrawn from (x^-, P^-) (001 eq. 11; FilterPy does the same)::

        Z_i = h(chi_i),  z^ = sum W_m^i Z_i                             (001 eq. 14)
        P_xz = sum W_c^i (chi_i - x^-)(Z_i - z^)^T                      (001 eq. 15)
        S = sum W_c^i (Z_i - z^)(Z_i - z^)^T + R                        (001 eqs. 16-17)
        K = P_xz S^-1,  x^+ = x^- + K (z - z^),  P^+ = P^- - K S K^T     (001 eqs. 18-20)

    computed without an inverse: ``W = L_y^-1 P_xz^T``, ``w = L_y^-1 y`` (L_y = chol S), then
    ``K y = W^T w``, ``K S K^T = W^T W``, NIS = ``w^T w``. Weights: sigma_points.py. Differences of
    measurements go through ``model.residual`` (angle wrapping); P is symmetrised after every step.

    ``augmented: true`` samples the noise too: the state is augmented with w ~ N(0, Q) in the
    prediction and with v ~ N(0, R) in the update (2n+1 -> 2(n+q)+1 points); the models may define
    ``f_with_noise(x, w, u, dt)`` and ``h_with_noise(x, v)`` for noise that enters non-linearly
    (default ``f(x, u, dt) + w`` and ``h(x) + v``). The augmented prediction always uses sigma points.

    Defaults alpha=0.5, beta=2, kappa=0 (Stone Soup's). Small alpha (1e-3, common in the literature)
    puts the points within 1e-3 sigma of the mean, so the transform differences h over tiny steps and
    weights them by ~1e5-1e6: it agrees with an extended-precision reference to ~1e-8 relative, against
    ~1e-14 at alpha = 0.5 (benchmarks/README.md).
    """

    name = "ukf"

    class Params(UnscentedParams):
        """Scaled unscented transform parameters, prediction mode and noise augmentation."""

        augmented: bool = Field(False, description="augment the state with the process and measurement "
                                                   "noise (for noise entering non-linearly)")

    # ------------------------------------------------------------------ predict
    def predict(self, belief: Belief, process: ProcessModel, u: np.ndarray | None, dt: float) -> Belief:
        if dt == 0.0:
            return belief
        if self.use_linear_prediction(process):
            x1, F, Q = linearised_predict(belief, process, u, dt)
            return Belief(belief.t + dt, x1, P=linear_predict(belief.x, covariance_of(belief), F, Q))
        Q = process.Q(belief.x, u, dt)
        if self._augmented:
            return self._predict_augmented(belief, process, u, dt, covariance_of(belief), Q)
        return self.sigma_predict(belief, process, lambda X: process.f(X, u, dt), lambda x0, x1: Q, dt)

    def sigma_predict(self, belief: Belief, process: ProcessModel, propagate, noise, dt: float) -> Belief:
        x = belief.x
        sp = self.sigma_points(x.shape[0])
        L, _, event = self.factor(covariance_of(belief), belief.t, "ukf predict")   # L L^T = P
        dX = sp.E @ L.T
        Y = propagate(x + dX)                                # 000 eq. 4, one call
        xm = sp.Wm @ Y                                       # 000 eq. 5
        D = Y - xm
        xm = process.normalize(xm)
        P1 = (D.T * sp.Wc) @ D + noise(x, xm)
        return Belief(belief.t + dt, xm, P=symmetrise(P1), events=(event,) if event is not None else ())

    def _predict_augmented(self, belief, process, u, dt, P, Q) -> Belief:
        n = belief.x.shape[0]
        sp = self.sigma_points(2 * n)
        La = np.zeros((2 * n, 2 * n))
        La[:n, :n], _, event = self.factor(P, belief.t, "ukf predict")
        La[n:, n:] = psd_sqrt_rows(Q).T
        dX = sp.E @ La.T
        X = belief.x + dX[:, :n]
        W = dX[:, n:]
        if has(process, NonAdditiveProcessNoise):
            Y = process.f_with_noise(X, W, u, dt)
        else:
            Y = process.f(X, u, dt) + W
        xm = sp.Wm @ Y
        D = Y - xm
        return Belief(belief.t + dt, process.normalize(xm), P=symmetrise((D.T * sp.Wc) @ D),
                      events=(event,) if event is not None else ())

    # ------------------------------------------------------------------ update (SigmaPointFilter.update)
    def prior_factor(self, belief: Belief, events: list) -> tuple[np.ndarray, np.ndarray]:
        L, P, event = self.factor(covariance_of(belief), belief.t, "ukf update")   # L L^T = P (repaired if need be)
        if event is not None:
            events.append(event)
        return L, P

    def measure_augmented(self, belief: Belief, L: np.ndarray, model: MeasurementModel, R, m: int):
        """The points also sample v ~ N(0, R): R is then in them."""
        n = belief.x.shape[0]
        sp = self.sigma_points(n + m)
        La = np.zeros((n + m, n + m))
        La[:n, :n] = L
        La[n:, n:] = psd_sqrt_rows(as_covariance(R, m)).T
        dXa = sp.E @ La.T
        dX = dXa[:, :n]
        if has(model, NonAdditiveMeasurementNoise):
            Z = model.h_with_noise(belief.x + dX, dXa[:, n:])
        else:
            Z = model.h(belief.x + dX) + dXa[:, n:]
        return sp, dX, Z, residual_of(model)

    def innovation(self, sp, dX, Z, diff, z, R, P, t, events):
        """S and P_xz as sums (001 eqs. 14-17), S factored; ``W = L_y^-1 P_xz^T`` (C = W^T) and w from one
        triangular solve, P^+ = P^- - W^T W (001 eqs. 18-20)."""
        zm = sp.Wm @ Z
        dZ = diff(Z, zm)
        A = dZ * sp.Wc_col
        S = dZ.T @ A                                           # 001 eq. 16
        if R is not None:
            S += as_covariance(R, Z.shape[1])                  # 001 eq. 17
        Ly, S, event = self.factor(S, t, "ukf innovation covariance")
        if event is not None:
            events.append(event)
        # [P_xz; y^T] (n + 1, m) in one buffer, so that one triangular solve gives both
        # W = L_y^-1 P_xz^T and w = L_y^-1 y (its transpose is Fortran-ordered: no copy for BLAS)
        n = dX.shape[1]
        B = np.empty((n + 1, Z.shape[1]))
        np.matmul(dX.T, A, out=B[:n])                          # 001 eq. 15
        y = B[n] = diff(z, zm)
        V = _dtrsm(1.0, Ly, B.T, 0, 1, 0, 0, 1)               # (m, n + 1) = L_y^-1 [P_xz^T, y] (left, lower, overwrite_b)
        W = V[:, :n]
        # W.T @ W is computed by BLAS syrk (numpy detects a.T @ a), exactly symmetric, so P^+ is exactly
        # symmetric when P is (tests/filters/test_filters_exactness.py checks it bit for bit)
        return y, S, V[:, n], W, P - W.T @ W                   # 001 eq. 20
