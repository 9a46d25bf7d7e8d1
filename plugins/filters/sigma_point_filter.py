"""The base of the sigma-point filters (ukf, srukf): cached weights, the choice of prediction, the batched
prediction over a run of input samples, and the sigma-point measurement transform both updates use."""
from __future__ import annotations

import numpy as np

from fusion.api import Belief, InputRunNoise, IntegratesInputRuns, MeasurementModel, ProcessModel, has

from .base import KalmanBase, residual_of
from .checks import MEAN, SIGMA, array_of, finite, frozen, trusted
from .sigma_points import SigmaPoints

__all__ = ["SigmaPointFilter", "measurement_transform"]


def measurement_transform(sp: SigmaPoints, x: np.ndarray, L: np.ndarray, model: MeasurementModel, m: int):
    """The sigma points' deviations ``dX`` (2n+1, n) from the mean x (n,) for the lower factor L of P
    (P = L L^T), the predicted measurements ``Z = h(x + dX)`` (2n+1, m) in ONE call of h (paper 001
    eq. 14, paper 000 eq. 8), and the model's difference function (``residual``, or plain subtraction).
    Z is checked (shape (2n+1, m), finite at finite points: checks.py), a bad one raising ModelFault."""
    dX = sp.E @ L.T
    Z = model.h(x + dX)
    if not trusted(model):
        Z = array_of(Z, (dX.shape[0], m), "h", SIGMA)
        finite(Z, "h", SIGMA, x, dX)
    return dX, Z, residual_of(model)


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
            if trusted(process):
                return Q_inputs(x0, x1, us, dts)
            return self.check_Q(Q_inputs(frozen(x0), frozen(x1), us, dts), x0.shape[0], "Q_inputs", MEAN, x0, x1)

        return self.sigma_predict(belief, process, propagate, noise, float(dts.sum()))

    def sigma_predict(self, belief: Belief, process: ProcessModel, propagate, noise, dt: float) -> Belief:
        """The sigma-point prediction over ``dt``: ``propagate(X)`` maps the (2n+1, n) points, ``noise(x,
        x1)`` gives the process noise from the prior mean x and the (normalised) predicted mean x1."""
        raise NotImplementedError
