"""Building blocks shared by the five filters (Stone Soup style: share the math, not five monoliths).

* :class:`KalmanBase`: the Filter base: the not-positive-definite detection and repair (returned as a
  value, :class:`Factor`), gating, the layout's normalisation of the updated mean. No state.
* :func:`linearised_predict`: the linearised prediction's terms (paper 001 eqs. 9-10), for ekf, ukf and
  srukf; :func:`linear_predict` its covariance ``F P F^T + Q``.
* :func:`linearised_update`: the Kalman update about a linearisation point, the step the EKF does once
  and the IEKF iterates. One iteration (kf, ekf) runs in C when the kernel is built
  (``fusion_plugins.filters._kalman_kernel``, _kalman_kernel.c: ~3 us against ~40 us of numpy calls at
  n = 22, m = 3); :func:`linearised_update_numpy` is the reference and runs otherwise.

Notation (FilterPy / textbook): x, P the belief; F, Q process; H, R measurement; y the innovation;
S = H P H^T + R its covariance (``Pzz``), L_y its lower Cholesky factor; K = P H^T S^-1 the gain.
No explicit inverse anywhere: with ``W = L_y^-1 (P H^T)^T`` and ``w = L_y^-1 y``,
``K y = W^T w``, ``K S K^T = W^T W`` and ``y^T S^-1 y = w^T w`` (the NIS).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fusion import kernels
from fusion.api import Belief, Event, Filter, Gate, MeasurementModel, ProcessModel, UpdateResult

from .jacobian import measurement_jacobian, process_jacobian
from .linalg import cholesky_lower, recover_factor, solve_lower, symmetrise

__all__ = ["KalmanBase", "Factor", "linear_predict", "linearised_predict", "linearised_update",
           "linearised_update_numpy", "as_covariance", "covariance_of", "as_vector", "residual_of", "KERNEL",
           "KERNEL_MAX_STATES"]

#: the compiled covariance arithmetic (_kalman_kernel.c: the EKF's chain, the one-iteration update), or None:
#: not built, or FUSION_PURE_PYTHON=1 at import (fusion/kernels.py)
KERNEL = kernels.load("fusion_plugins.filters._kalman_kernel")
#: the kernel's products (no blocking) beat BLAS's only for small matrices: more states use numpy
KERNEL_MAX_STATES = 64

_ndarray = np.ndarray
_float64 = np.dtype(float)


def as_vector(z) -> np.ndarray:
    """z as a flat float64 array (the array itself when it already is one: ~0.1 us against ~0.7 us for
    ``np.asarray(z, dtype=float).reshape(-1)``)."""
    if type(z) is _ndarray and z.ndim == 1 and z.dtype == _float64:
        return z
    return np.asarray(z, dtype=float).reshape(-1)


_default_residual = MeasurementModel.residual


def residual_of(model: MeasurementModel):
    """``model.residual``, or ``np.subtract`` (the same z - z_hat, without a Python call) when the model
    keeps MeasurementModel's default."""
    return np.subtract if getattr(type(model), "residual", None) is _default_residual else model.residual


def as_covariance(R, m: int) -> np.ndarray:
    """R as an (m, m) array: a matrix as is, a vector of m variances, or a scalar variance."""
    if type(R) is _ndarray and R.dtype == _float64 and R.shape == (m, m):
        return R
    R = np.asarray(R, dtype=float)
    if R.ndim == 2:
        if R.shape != (m, m):
            raise ValueError(f"measurement covariance R has shape {R.shape}, expected ({m}, {m})")
        return R
    if R.ndim == 0:
        return np.eye(m) * float(R)
    if R.shape != (m,):
        raise ValueError(f"measurement variances R have shape {R.shape}, expected ({m},) or ({m}, {m})")
    return np.diag(R)


def covariance_of(belief: Belief) -> np.ndarray:
    """P of a belief (from S when it is a square-root belief)."""
    return belief.P if belief.P is not None else belief.cov


def linear_predict(x: np.ndarray, P: np.ndarray, F: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """Predicted covariance ``F P F^T + Q`` (paper 001 eq. 10), symmetrised."""
    return symmetrise(F @ P @ F.T + Q)


class Factor(NamedTuple):
    """What :meth:`KalmanBase.factor` returns: ``L`` the lower Cholesky factor, ``P`` the covariance it
    factors (the input, or its repair ``L L^T`` when the input was not positive definite) and ``event``
    (the ``not_positive_definite`` Event of a repair, else None)."""

    L: np.ndarray
    P: np.ndarray
    event: Event | None


class KalmanBase(Filter):
    """Common base of kf, ekf, iekf, ukf and srukf. A filter keeps no state: everything it has to report
    comes back as a value: a prediction's events on the returned belief (``Belief.events``), an update's
    on its ``UpdateResult.events`` (with ``iterations``); the run counts and reports them.

    The updated mean is brought back to the state's manifold by the layout's unit quaternion blocks
    (``StateLayout.normalize``): the filter's own layout (the system's, given at wiring), else the
    measurement model's. The predicted mean by the process model's ``normalize``.

    The filters call their models as they are: a plugin's models are wrapped at wiring by the checking
    adapter (plugins/filters/checks.py ``checked``), which gives them read-only views and checks every value
    they return (a bad one raises ModelFault, which the run charges to the model).
    """

    # ------------------------------------------------------------------ diagnostics
    def event(self, t: float, kind: str, detail: str = "") -> Event:
        """An Event of ``kind`` from this filter (sensor None)."""
        return Event(float(t), kind, None, f"{self.name}: {detail}" if detail else self.name)

    def factor(self, P: np.ndarray, t: float, where: str) -> Factor:
        """Lower Cholesky factor of P; a non-positive-definite P is repaired (eigenvalue clipping) and
        the repair returned, with its event."""
        L, ok = cholesky_lower(P)
        if ok:
            return Factor(L, P, None)
        L = recover_factor(P)
        return Factor(L, L @ L.T, self.event(t, "not_positive_definite",
                                             f"{where}: covariance not positive definite, repaired"))

    def normalizer(self, model: MeasurementModel):
        """The layout normalisation for an update with ``model``: the filter's layout, else the model's."""
        lay = self.context.layout
        if lay is None:
            lay = model.context.layout
        return lay.normalize if lay is not None else _identity

    def rejected(self, belief: Belief, y: np.ndarray, S: np.ndarray, nis: float, gate: Gate | None,
                 m: int, events: tuple = (), iterations: int = 1) -> UpdateResult | None:
        """The UpdateResult of a measurement the gate rejects (belief untouched), else None."""
        if gate is None or gate.accept(nis, m):
            return None
        return UpdateResult(belief, y, S, nis, False, events, iterations)

    # ------------------------------------------------------------------ interface
    def initial_belief(self, t: float, x: np.ndarray, P: np.ndarray) -> Belief:
        x = np.array(x, dtype=float)
        P = symmetrise(np.array(P, dtype=float))
        if P.shape != (x.shape[0], x.shape[0]):
            raise ValueError(f"initial covariance has shape {P.shape}, expected {(x.shape[0],) * 2}")
        return Belief(float(t), x, P=P)

    def predict(self, belief: Belief, process: ProcessModel, u: np.ndarray | None, dt: float) -> Belief:
        raise NotImplementedError

    def predict_inputs(self, belief: Belief, process: ProcessModel, us: np.ndarray, dts: np.ndarray) -> Belief:
        """Integrate a run of input samples in order: ``us`` (k, m), sample j held over ``dts[j]`` (s).
        The scheduler passes the samples between two measurements in one call. Here: k calls of
        :meth:`predict` (the same numbers as sample by sample), their events gathered on the result; the
        sigma-point filters override it."""
        events: tuple = ()
        for u, dt in zip(us, dts):
            belief = self.predict(belief, process, u, float(dt))
            if belief.events:
                events += belief.events
        return belief.with_(events=events) if events else belief

    def update(self, belief: Belief, model: MeasurementModel, z: np.ndarray, R: np.ndarray,
               gate: Gate | None = None) -> UpdateResult:
        raise NotImplementedError


def _identity(x: np.ndarray) -> np.ndarray:
    return x


def linearised_predict(belief: Belief, process: ProcessModel, u: np.ndarray | None,
                       dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The linearised prediction's terms (paper 001 eqs. 9-10), shared by ekf, ukf and srukf::

        x^- = normalize(f(x, u, dt)),   F = df/dx (x, u, dt),   Q = Q(x, u, dt)

    returned as ``(x^-, F, Q)``; the covariance (``F P F^T + Q``, or its square root) is the caller's."""
    x = belief.x
    F = process_jacobian(process, x, u, dt)
    Q = process.Q(x, u, dt)
    return process.normalize(process.f(x, u, dt)), F, Q


_EYE: dict[int, np.ndarray] = {}


def _eye(n: int) -> np.ndarray:
    I = _EYE.get(n)
    if I is None:
        I = _EYE[n] = np.eye(n)
        I.flags.writeable = False
    return I


def linearised_update(flt: KalmanBase, belief: Belief, model: MeasurementModel, z: np.ndarray,
                      R: np.ndarray, gate: Gate | None, max_iterations: int = 1,
                      tolerance: float = 0.0) -> UpdateResult:
    """The (iterated) extended Kalman update (:func:`linearised_update_numpy`, the equations); one iteration
    in C when the kernel is loaded (:func:`_update_compiled`), the same numbers to the last bit or two."""
    if KERNEL is not None and max_iterations == 1:
        out = _update_compiled(flt, belief, model, z, R, gate)
        if out is not None:
            return out
    return linearised_update_numpy(flt, belief, model, z, R, gate, max_iterations, tolerance)


def _update_compiled(flt: KalmanBase, belief: Belief, model: MeasurementModel, z: np.ndarray, R: np.ndarray,
                     gate: Gate | None) -> UpdateResult | None:
    """:func:`linearised_update_numpy` with ``max_iterations=1``, its arithmetic in one C call
    (_kalman_kernel.c ``update``: S, the NIS, and the mean and Joseph-form covariance the gate then takes or
    leaves), the model's calls and checks unchanged (h is evaluated before S is factored: neither has side
    effects). None when the numpy code must run instead:
    more than KERNEL_MAX_STATES states, or S not positive definite (its repair and event are the numpy
    code's)."""
    x0 = belief.x
    n = x0.shape[0]
    if n > KERNEL_MAX_STATES:
        return None
    P = covariance_of(belief)
    z = as_vector(z)
    m = z.shape[0]
    R = as_covariance(R, m)
    H = measurement_jacobian(model, x0)
    r = residual_of(model)(z, model.h(x0))
    S, x1, P1 = np.empty((m, m)), np.empty(n), np.empty((n, n))
    try:                                         # the arrays as they are (nearly always float64, C-ordered)
        nis = KERNEL.update(x0, P, H, R, r, S, x1, P1)
    except (TypeError, ValueError):              # else contiguous float64 copies (a wrong shape raises again)
        nis = KERNEL.update(*(np.ascontiguousarray(a, dtype=float) for a in (x0, P, H, R, r)), S, x1, P1)
    if nis is None:
        return None
    out = flt.rejected(belief, r, S, nis, gate, m)
    if out is not None:
        return out
    return UpdateResult(Belief(belief.t, flt.normalizer(model)(x1), P=P1), r, S, nis, True, (), 1)


def linearised_update_numpy(flt: KalmanBase, belief: Belief, model: MeasurementModel, z: np.ndarray,
                            R: np.ndarray, gate: Gate | None, max_iterations: int = 1,
                            tolerance: float = 0.0) -> UpdateResult:
    """The (iterated) extended Kalman update; ``max_iterations=1`` is the EKF / linear KF update.

    Iteration i linearises h about x_i (x_0 = x^-, the prior mean), Gauss-Newton on the MAP cost
    ``|x - x^-|^2_{P^-1} + |z - h(x)|^2_{R^-1}`` (Bell & Cathey 1993)::

        H_i = dh/dx (x_i),   S_i = H_i P H_i^T + R,   K_i = P H_i^T S_i^-1
        x_{i+1} = x^- + K_i (z - h(x_i) - H_i (x^- - x_i))

    until ``max|x_{i+1} - x_i| <= tolerance`` or ``max_iterations``. The covariance is the Joseph form
    with the last K, H: ``P^+ = (I - K H) P (I - K H)^T + K R K^T`` (symmetrised). The innovation,
    its covariance, the NIS and the gate decision are those of the prior (iteration 0), the same as
    the EKF's.
    """
    x0 = belief.x
    n = x0.shape[0]
    P = covariance_of(belief)
    z = np.asarray(z, dtype=float).reshape(-1)
    m = z.shape[0]
    R = as_covariance(R, m)
    xi = x0
    events: tuple = ()
    for it in range(max_iterations):
        H = measurement_jacobian(model, xi)
        HP = H @ P                               # (P H^T)^T, P symmetric
        Ly, S, event = flt.factor(HP @ H.T + R, belief.t, "innovation covariance")
        if event is not None:
            events += (event,)
        r = model.residual(z, model.h(xi))
        W = solve_lower(Ly, HP)                  # L_y^-1 H P   (m, n)
        if it == 0:
            y0, S0 = r, S
            w = solve_lower(Ly, r)
            nis = float(w @ w)
            out = flt.rejected(belief, y0, S0, nis, gate, m, events)
            if out is not None:
                return out
        else:
            w = solve_lower(Ly, r - H @ (x0 - xi))
        x_next = x0 + w @ W                      # x^- + K r,  K r = W^T L_y^-1 r
        if max_iterations == 1:
            xi = x_next
            break
        step = np.abs(x_next - xi).max()
        xi = x_next
        if step <= tolerance:
            break
    iterations = it + 1
    Kt = solve_lower(Ly, W, trans=1)             # K^T = S^-1 H P   (m, n)
    A = _eye(n) - Kt.T @ H                      # I - K H
    P1 = symmetrise(A @ P @ A.T + Kt.T @ R @ Kt)  # Joseph form
    return UpdateResult(Belief(belief.t, flt.normalizer(model)(xi), P=P1), y0, S0, nis, True, events, iterations)
