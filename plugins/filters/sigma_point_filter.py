"""The base of the sigma-point filters (ukf, srukf): cached weights, the choice of prediction, the batched
prediction over a run of input samples, and the one sigma-point update both use (they differ only in how the
innovation's square root, the gain and the posterior's covariance or square root are formed)."""
from __future__ import annotations

import numpy as np

from fusion.api import (Belief, Gate, InputRunNoise, IntegratesInputRuns, MeasurementModel, ProcessModel,
                        UpdateResult, has)

from .base import KalmanBase, as_vector, residual_of
from .sigma_points import SigmaPoints

__all__ = ["SigmaPointFilter"]


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
        """Weights and deviation pattern for dimension n (a pure function of n and the params, memoised)."""
        sp = self._sp.get(n)
        if sp is None:
            p = self.params
            sp = self._sp[n] = SigmaPoints(n, p.alpha, p.beta, p.kappa)
        return sp

    def use_linear_prediction(self, process: ProcessModel) -> bool:
        mode = self._mode
        return mode == "always" or (mode == "auto" and process.linear and not self._augmented)

    def batches_inputs(self, process: ProcessModel, k: int) -> bool:
        """Whether :meth:`predict_inputs` integrates a run of ``k`` samples of ``process`` in one
        sigma-point step (else: k predictions, sample by sample). The smoother's recorder asks the same,
        so its transition terms are those of what the filter did."""
        return (k > 1 and self._batch_inputs and not self._augmented and not self.use_linear_prediction(process)
                and has(process, InputRunNoise))

    def predict_inputs(self, belief: Belief, process: ProcessModel, us: np.ndarray, dts: np.ndarray) -> Belief:
        r"""Integrate a run of k input samples (IMU) between two measurements in one sigma-point step.

        ``us`` (k, m), sample j held over ``dts[j]`` (s), T = sum dts. The sigma points are drawn once,
        from the belief at the start of the run, and carried through all k samples (``process.f_inputs``
        when the model has the capability IntegratesInputRuns, one vectorised call for the whole run, else
        k calls of ``f`` on all points); the mean and covariance (or its square root) are formed once at
        the end, with the process noise of the whole interval added once::

            chi = [x, x +- eta S_i];  Y_i = f(... f(f(chi_i, u_1, dt_1), u_2, dt_2) ..., u_k, dt_k)
            x^- = sum W_m^i Y_i;      P^- = sum W_c^i (Y_i - x^-)(Y_i - x^-)^T + Q_T

        Q_T is ``process.Q_inputs(x, x^-, us, dts)`` (InputRunNoise; ins: the noise of the interval
        propagated through the error dynamics). A model without InputRunNoise is predicted sample by
        sample: a single ``Q(x^-, mean u, T)`` added at the end leaves out the early samples' noise
        carried through the later dynamics (a unicycle over 100 samples: sd 13% too small), so a
        missing optional capability costs speed, not correctness. So are ``batch_inputs: false``, a
        single sample, the linear prediction and the augmented UKF (:meth:`batches_inputs`).
        The same as k predictions sample by sample when f is linear and Q_T is the propagated sum; for
        the INS it differs from them by the sigma points not being redrawn after each sample
        (tests/filters/test_predict_inputs.py states the tolerances)."""
        if not self.batches_inputs(process, len(dts)):
            return super().predict_inputs(belief, process, us, dts)
        us = np.asarray(us, dtype=float)
        dts = np.asarray(dts, dtype=float)
        f_inputs = process.f_inputs if has(process, IntegratesInputRuns) else None
        Q_inputs = process.Q_inputs

        def propagate(X: np.ndarray) -> np.ndarray:
            if f_inputs is not None:
                return f_inputs(X, us, dts)
            for u, dt in zip(us, dts):
                X = process.f(X, u, float(dt))
            return X

        def noise(x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
            return Q_inputs(x0, x1, us, dts)

        return self.sigma_predict(belief, process, propagate, noise, float(dts.sum()))

    def sigma_predict(self, belief: Belief, process: ProcessModel, propagate, noise, dt: float) -> Belief:
        """The sigma-point prediction over ``dt``: ``propagate(X)`` maps the (2n+1, n) points, ``noise(x,
        x1)`` gives the process noise from the prior mean x and the (normalised) predicted mean x1."""
        raise NotImplementedError

    # ------------------------------------------------------------------ update
    #: whether the belief holds the square root S (srukf) rather than P (ukf)
    square_root = False

    def update(self, belief: Belief, model: MeasurementModel, z: np.ndarray, R: np.ndarray,
               gate: Gate | None = None) -> UpdateResult:
        r"""The sigma-point update (paper 001 eqs. 14-20; paper 000 Algorithm 1, eqs. 8-16), with sigma points
        redrawn from the prior (x^-, L), L L^T = P^-::

            Z_i = h(x^- + dX_i)  (one call),   z^ = sum W_m^i Z_i,   y = residual(z, z^)
            L_y L_y^T = S = sum W_c^i (Z_i - z^)(Z_i - z^)^T + R
            G = L_y^-1 P_xz^T,   w = L_y^-1 y,   NIS = w^T w,   x^+ = x^- + G^T w   (K y = P_xz S^-1 y)
            P^+ = P^- - G^T G

        :meth:`innovation` is where the filters differ: the ukf forms S and P_xz as sums and factors S; the
        srukf gets L_y, G and the posterior's square root from one QR (its docstring)."""
        x = belief.x
        z = as_vector(z)
        m = z.shape[0]
        events: list = []
        L, prior = self.prior_factor(belief, events)
        if self._augmented:
            sp, dX, Z, diff = self.measure_augmented(belief, L, model, R, m)
            R = None
        else:
            sp = self.sigma_points(x.shape[0])
            dX = sp.E @ L.T
            Z = model.h(x + dX)                                  # one call (001 eq. 14, 000 eq. 8)
            diff = residual_of(model)
        y, S, w, G, post = self.innovation(sp, dX, Z, diff, z, R, prior, belief.t, events)
        nis = float(w.dot(w))
        if gate is not None and not gate.accept(nis, m):
            return UpdateResult(belief, y, S, nis, False, tuple(events), 0)
        x1 = self.normalizer(model)(x + w @ G)                   # 001 eqs. 18-19, 000 eq. 14
        b = Belief(belief.t, x1, S=post) if self.square_root else Belief(belief.t, x1, P=post)
        return UpdateResult(b, y, S, nis, True, tuple(events), 0)

    def prior_factor(self, belief: Belief, events: list) -> tuple[np.ndarray, np.ndarray]:
        """``(L, prior)``: L the lower factor of the prior's covariance (a repair's event appended to
        ``events``), ``prior`` what the posterior is formed from (the ukf's P, the srukf's S = L)."""
        raise NotImplementedError

    def measure_augmented(self, belief: Belief, L: np.ndarray, model: MeasurementModel, R, m: int):
        """``(sp, dX, Z, diff)`` of the augmented form (the ukf's ``augmented: true``)."""
        raise NotImplementedError

    def innovation(self, sp: SigmaPoints, dX: np.ndarray, Z: np.ndarray, diff, z: np.ndarray, R,
                   prior: np.ndarray, t: float, events: list):
        """``(y, S, w, G, post)``: the innovation ``y = residual(z, z^)``, its covariance S, the whitened
        innovation ``w = L_y^-1 y`` (L_y L_y^T = S), ``G = L_y^-1 P_xz^T`` (so K y = w G) and the posterior's
        P (ukf) or S (srukf). R is None when the points already carry the noise (augmented)."""
        raise NotImplementedError
