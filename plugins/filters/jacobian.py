"""Numerical Jacobian, the fallback of the EKF/IEKF when a model has no analytic ``jacobian``.

Central differences, vectorised: the function is evaluated ONCE on a ``(2n, n)`` batch of perturbed
states (models are vectorised over leading axes, DESIGN.md), so a Jacobian costs one model call.
Truncation error O(h^2) with ``h = eps^(1/3) max(|x_i|, 1)``; rounding error O(eps |f| / h): about
1e-10 relative, exact to rounding for affine functions.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

__all__ = ["numerical_jacobian", "process_jacobian", "measurement_jacobian"]

_REL_STEP = np.finfo(float).eps ** (1.0 / 3.0)


def numerical_jacobian(fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray,
                       difference: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
                       rel_step: float = _REL_STEP) -> np.ndarray:
    """d fun / dx (m, n) at ``x`` (n,) by central differences.

    :param fun: vectorised function, ``(k, n) -> (k, m)``; called once with ``k = 2n``.
    :param difference: ``difference(a, b)`` = a - b for outputs (e.g. a measurement's ``residual`` to
        wrap angles); plain subtraction when None.
    """
    x = np.asarray(x, dtype=float)
    n = x.shape[0]
    h = rel_step * np.maximum(np.abs(x), 1.0)
    X = np.empty((2 * n, n))
    X[:] = x
    idx = np.arange(n)
    X[idx, idx] += h
    X[n + idx, idx] -= h
    step = X[idx, idx] - X[n + idx, idx]  # the step actually taken, after rounding of x +- h
    Y = fun(X)
    dY = Y[:n] - Y[n:] if difference is None else difference(Y[:n], Y[n:])
    return (dY / step[:, None]).T


def process_jacobian(process, x: np.ndarray, u, dt: float) -> np.ndarray:
    """The process model's analytic F = df/dx (n, n) at x, or the numerical one when it has none."""
    F = process.jacobian(x, u, dt)
    if F is None:
        F = numerical_jacobian(lambda X: process.f(X, u, dt), x)
    return F


def measurement_jacobian(model, x: np.ndarray) -> np.ndarray:
    """The measurement model's analytic H = dh/dx (m, n) at x, or the numerical one when it has none."""
    H = model.jacobian(x)
    if H is None:
        H = numerical_jacobian(model.h, x, model.residual)
    return H if type(H) is np.ndarray and H.ndim == 2 else np.atleast_2d(H)
