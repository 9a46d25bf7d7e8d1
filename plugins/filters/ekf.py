"""ekf: the extended Kalman filter (papers 001, 002 and 003 use it)."""
from __future__ import annotations

import numpy as np

from fusion.api import Belief, Gate, LinearisesInputRuns, MeasurementModel, Params, ProcessModel, UpdateResult, has

from . import base
from .base import KalmanBase, covariance_of, linear_predict, linearised_predict, linearised_update
from .linalg import symmetrise


class ExtendedKalmanFilter(KalmanBase):
    r"""Extended Kalman filter: linearised prediction and update.

    Prediction (paper 001 eqs. 9-10 with F the Jacobian at the prior mean)::

        x^- = normalize(f(x, u, dt)),   F = df/dx (x, u, dt),   P^- = F P F^T + Q(x, u, dt)

    Update (H = dh/dx at the prior mean)::

        y = residual(z, h(x^-)),   S = H P^- H^T + R,   K = P^- H^T S^-1
        x^+ = normalize(x^- + K y),   P^+ = (I - K H) P^- (I - K H)^T + K R K^T   (Joseph form)

    Jacobians: the model's analytic ``jacobian`` when it returns one, else central differences on one
    vectorised batch of 2n perturbed states (plugins/filters/jacobian.py). ``nis = y^T S^-1 y`` by a
    triangular solve with the Cholesky factor of S; a non-positive-definite S is repaired by eigenvalue
    clipping and reported (a ``not_positive_definite`` event in ``UpdateResult.events``).
    """

    name = "ekf"

    class Params(Params):
        """The EKF has no parameters."""

    def predict(self, belief: Belief, process: ProcessModel, u: np.ndarray | None, dt: float) -> Belief:
        if dt == 0.0:
            return belief
        x1, F, Q = linearised_predict(belief, process, u, dt)
        return Belief(belief.t + dt, x1, P=linear_predict(belief.x, covariance_of(belief), F, Q))

    def predict_inputs(self, belief: Belief, process: ProcessModel, us: np.ndarray, dts: np.ndarray) -> Belief:
        """A run of input samples: when the process model linearises the whole run in one call
        (LinearisesInputRuns: the INS's means, F_j and Q_j vectorised over the samples), the covariance
        is propagated through them, ``P <- F_j P F_j^T + Q_j`` sample by sample (symmetrised once, at the
        end of the run: ~2 us a sample less), the same numbers as k calls of :meth:`predict` to rounding;
        otherwise k calls of :meth:`predict`. The chain runs in C when the kernel is built (_kalman_kernel.c:
        F's nonzeros only, the upper triangle; ~1 us a sample against ~5 us), else :func:`propagate_run`."""
        run = process.linearise_inputs(belief.x, us, dts) if has(process, LinearisesInputRuns) else None
        if run is None:
            return super().predict_inputs(belief, process, us, dts)
        x1, F, Q = run
        P = covariance_of(belief)
        n = P.shape[0]
        kernel = base.KERNEL
        if kernel is not None and n <= base.KERNEL_MAX_STATES:
            P1 = np.empty((n, n))
            kernel.propagate(np.ascontiguousarray(P, dtype=float), np.ascontiguousarray(F, dtype=float),
                             np.ascontiguousarray(Q, dtype=float), P1)
        else:
            P1 = propagate_run(P, F, Q)
        # sum() adds left to right from belief.t: the same time as t += dt sample by sample
        return Belief(sum(np.asarray(dts, dtype=float).tolist(), belief.t), x1, P=P1)

    def update(self, belief: Belief, model: MeasurementModel, z: np.ndarray, R: np.ndarray,
               gate: Gate | None = None) -> UpdateResult:
        return linearised_update(self, belief, model, z, R, gate, max_iterations=1)


def propagate_run(P: np.ndarray, F: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """The covariance after a run, ``P <- F_j P F_j^T + Q_j`` for F, Q (k, n, n), symmetrised at the end:
    the numpy code (the reference of the compiled kernel, and what runs without it)."""
    for Fj, Qj in zip(F, Q):
        P = Fj @ P @ Fj.T
        P += Qj
    return symmetrise(P)
