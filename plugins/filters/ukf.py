"""ukf: the unscented Kalman filter (papers 000 and 001)."""
from __future__ import annotations

import numpy as np
from pydantic import Field

from fusion.api import Belief, Gate, MeasurementModel, ProcessModel, UpdateResult

from scipy.linalg import blas

from .base import (KalmanBase, as_covariance, as_vector, covariance_of, linear_predict,
                   residual_of)
from .jacobian import process_jacobian
from .linalg import psd_sqrt_rows, symmetrise

_dtrsm = blas.dtrsm
from .sigma_points import SigmaPoints, UnscentedParams


class SigmaPointFilter(KalmanBase):
    """Base of ukf and srukf: the cached sigma-point weights and the choice of prediction."""

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        self._sp: dict[int, SigmaPoints] = {}
        # read once: a missing pydantic attribute costs ~5 us through its AttributeError
        self._mode = self.params.linear_prediction
        self._augmented = bool(getattr(self.params, "augmented", False))
        self._batch_inputs = bool(self.params.batch_inputs)
        if self.context.layout is not None:   # wired for a state: bad alpha/beta/kappa are a config error
            self.sigma_points(self.context.layout.n)

    def sigma_points(self, n: int) -> SigmaPoints:
        """Weights and deviation pattern for dimension n (cached)."""
        sp = self._sp.get(n)
        if sp is None:
            p = self.params
            sp = self._sp[n] = SigmaPoints(n, p.alpha, p.beta, p.kappa)
        return sp

    def use_linear_prediction(self, process: ProcessModel) -> bool:
        mode = self._mode
        return mode == "always" or (mode == "auto" and process.linear and not self._augmented)

    def predict_inputs(self, belief: Belief, process: ProcessModel, us: np.ndarray, dts: np.ndarray) -> Belief:
        r"""Integrate a run of k input samples (IMU) between two measurements in one sigma-point step.

        ``us`` (k, m), sample j held over ``dts[j]`` (s), T = sum dts. The sigma points are drawn once,
        from the belief at the start of the run, and carried through all k samples (``process.f_inputs``
        when the model has it, one vectorised call for the whole run, else k calls of ``f`` on all points);
        the mean and covariance (or its square root) are formed once at the end, with the process noise
        of the whole interval added once::

            chi = [x, x +- eta S_i];  Y_i = f(... f(f(chi_i, u_1, dt_1), u_2, dt_2) ..., u_k, dt_k)
            x^- = sum W_m^i Y_i;      P^- = sum W_c^i (Y_i - x^-)(Y_i - x^-)^T + Q_T

        Q_T is ``process.Q_inputs(x, x^-, us, dts)`` when the model has it (ins: the noise of the interval
        propagated through the error dynamics), else ``process.Q(x^-, mean u, T)`` (exact for a linear
        time-invariant model such as pv). The same as k predictions sample by sample when f is linear
        and Q_T is the propagated sum; for the INS it differs from them by the sigma points not being
        redrawn after each sample (tests/filters/test_predict_inputs.py states the tolerances).
        ``batch_inputs: false``, a single sample, the linear prediction and the augmented UKF predict
        sample by sample."""
        k = len(dts)
        if k == 1 or not self._batch_inputs or self._augmented or self.use_linear_prediction(process):
            return super().predict_inputs(belief, process, us, dts)
        us = np.asarray(us, dtype=float)
        dts = np.asarray(dts, dtype=float)
        self.process = process
        self.counters["predicts"] += k
        self.counters["batched_predicts"] += 1
        f_inputs = getattr(process, "f_inputs", None)
        Q_inputs = getattr(process, "Q_inputs", None)

        def propagate(X: np.ndarray) -> np.ndarray:
            if f_inputs is not None:
                return f_inputs(X, us, dts)
            for u, dt in zip(us, dts):
                X = process.f(X, u, float(dt))
            return X

        def noise(x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
            if Q_inputs is not None:
                return Q_inputs(x0, x1, us, dts)
            return process.Q(x1, us.mean(axis=0), float(dts.sum()))

        return self.sigma_predict(belief, process, propagate, noise, float(dts.sum()))

    def sigma_predict(self, belief: Belief, process: ProcessModel, propagate, noise, dt: float) -> Belief:
        """The sigma-point prediction over ``dt``: ``propagate(X)`` maps the (2n+1, n) points, ``noise(x,
        x1)`` gives the process noise from the prior mean x and the (normalised) predicted mean x1."""
        raise NotImplementedError


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
        self.process = process
        if dt == 0.0:
            return belief
        x = belief.x
        P = covariance_of(belief)
        Q = process.Q(x, u, dt)
        self.counters["predicts"] += 1
        if self.use_linear_prediction(process):
            F = process_jacobian(process, x, u, dt)
            return Belief(belief.t + dt, process.normalize(process.f(x, u, dt)), P=linear_predict(x, P, F, Q))
        if self._augmented:
            return self._predict_augmented(belief, process, u, dt, P, Q)
        return self.sigma_predict(belief, process, lambda X: process.f(X, u, dt), lambda x0, x1: Q, dt)

    def sigma_predict(self, belief: Belief, process: ProcessModel, propagate, noise, dt: float) -> Belief:
        x = belief.x
        sp = self.sigma_points(x.shape[0])
        S = self.factor(covariance_of(belief), belief.t, "ukf predict")
        Y = propagate(x + sp.E @ S.T)                        # 000 eq. 4, one call
        xm = sp.Wm @ Y                                       # 000 eq. 5
        D = Y - xm
        xm = process.normalize(xm)
        P1 = (D.T * sp.Wc) @ D + noise(x, xm)
        return Belief(belief.t + dt, xm, P=symmetrise(P1))

    def _predict_augmented(self, belief, process, u, dt, P, Q) -> Belief:
        n = belief.x.shape[0]
        sp = self.sigma_points(2 * n)
        Sa = np.zeros((2 * n, 2 * n))
        Sa[:n, :n] = self.factor(P, belief.t, "ukf predict")
        Sa[n:, n:] = psd_sqrt_rows(Q).T
        dX = sp.E @ Sa.T
        X = belief.x + dX[:, :n]
        W = dX[:, n:]
        fn = getattr(process, "f_with_noise", None)
        Y = fn(X, W, u, dt) if fn is not None else process.f(X, u, dt) + W
        xm = sp.Wm @ Y
        D = Y - xm
        return Belief(belief.t + dt, process.normalize(xm), P=symmetrise((D.T * sp.Wc) @ D))

    # ------------------------------------------------------------------ update
    def update(self, belief: Belief, model: MeasurementModel, z: np.ndarray, R: np.ndarray,
               gate: Gate | None = None) -> UpdateResult:
        x = belief.x
        P = belief.P if belief.P is not None else belief.cov
        z = as_vector(z)
        m = z.shape[0]
        R = as_covariance(R, m)
        n = x.shape[0]
        S = self.factor(P, belief.t, "ukf update")
        if self.repaired is not None:
            P = self.repaired
        if self._augmented:
            sp = self.sigma_points(n + m)
            Sa = np.zeros((n + m, n + m))
            Sa[:n, :n] = S
            Sa[n:, n:] = psd_sqrt_rows(R).T
            dXa = sp.E @ Sa.T
            dX = dXa[:, :n]
            fn = getattr(model, "h_with_noise", None)
            Z = fn(x + dX, dXa[:, n:]) if fn is not None else model.h(x + dX) + dXa[:, n:]
            R = None
        else:
            sp = self.sigma_points(n)
            dX = sp.E @ S.T
            Z = model.h(x + dX)                                # 001 eq. 14, one call
        zm = sp.Wm @ Z
        diff = residual_of(model)
        dZ = diff(Z, zm)
        A = dZ * sp.Wc_col
        Pzz = dZ.T @ A                                         # 001 eq. 16
        if R is not None:
            Pzz += R                                           # 001 eq. 17
        Ly = self.factor(Pzz, belief.t, "ukf innovation covariance")
        if self.repaired is not None:
            Pzz = self.repaired
        # [P_xz; y^T] (n + 1, m) in one buffer, so that one triangular solve gives both
        # W = L_y^-1 P_xz^T and w = L_y^-1 y (its transpose is Fortran-ordered: no copy for BLAS)
        B = np.empty((n + 1, m))
        np.matmul(dX.T, A, out=B[:n])                          # 001 eq. 15
        y = B[n] = diff(z, zm)
        V = _dtrsm(1.0, Ly, B.T, 0, 1, 0, 0, 1)               # (m, n + 1) = L_y^-1 [P_xz^T, y] (left, lower, overwrite_b)
        W = V[:, :n]
        w = V[:, n]
        nis = float(w.dot(w))
        out = self.rejected(belief, y, Pzz, nis, gate, m)
        if out is not None:
            return out
        x1 = x + w @ W                                         # 001 eqs. 18-19
        P1 = P - W.T @ W                                       # 001 eq. 20
        # W.T @ W is computed by BLAS syrk (numpy detects a.T @ a), exactly symmetric, so P1 is exactly
        # symmetric when P is (tests/filters/test_filters_exactness.py checks it bit for bit)
        self.counters["updates"] += 1
        return UpdateResult(Belief(belief.t, self.normalize(x1), P=P1), y, Pzz, nis, True)
