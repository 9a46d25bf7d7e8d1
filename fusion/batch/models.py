"""Process and measurement quantities for N states at once: Q, F, H, R.

A model may give them batched itself (``Q_batch(x, u, dt) -> (N, n, n)``,
``jacobian_batch(x, u, dt) -> (N, n, n)`` on a process; ``jacobian_batch(x) -> (N, m, n)`` on a
measurement model), with ``x`` (N, n) and ``u`` None, (input_dim,) shared or (N, input_dim) per filter.
Otherwise these helpers call the single-state method once per filter (the same numbers; a Python loop,
so a model on the hot path of a sweep should have the batched method: pv, range and ins do), and a
missing analytic Jacobian becomes a central-difference one over all N states in one vectorised call
(the same steps as plugins/filters/jacobian.py).

Each helper returns an array that broadcasts against (N, ., .): a shared (n, n) matrix stays 2-D.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from fusion_plugins.filters.base import as_covariance
from fusion_plugins.filters.jacobian import _REL_STEP

__all__ = ["batch_Q", "batch_F", "batch_H", "batch_R", "numerical_jacobian_batch", "u_of", "propagate_cf", "CF_BLOCK"]


def u_of(u: np.ndarray | None, i: int) -> np.ndarray | None:
    """Filter i's input from a shared (m,) or per-filter (N, m) input."""
    if u is None:
        return None
    u = np.asarray(u, dtype=float)
    return u[i] if u.ndim == 2 else u


def batch_Q(process: Any, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
    """Discrete process noise (N, n, n) or a shared (n, n) at states x (N, n) over dt (s)."""
    fn = getattr(process, "Q_batch", None)
    if fn is not None:
        return fn(x, u, dt)
    return np.stack([process.Q(x[i], u_of(u, i), dt) for i in range(x.shape[0])])


def numerical_jacobian_batch(fun, x: np.ndarray, difference=None) -> np.ndarray:
    """d fun / dx (N, m, n) at x (N, n) by central differences; ``fun`` maps (N, 2n, n) -> (N, 2n, m)
    in one call (the steps of plugins.filters.jacobian.numerical_jacobian)."""
    N, n = x.shape
    h = _REL_STEP * np.maximum(np.abs(x), 1.0)
    X = np.repeat(x[:, None, :], 2 * n, axis=1)
    idx = np.arange(n)
    X[:, idx, idx] += h
    X[:, n + idx, idx] -= h
    step = X[:, idx, idx] - X[:, n + idx, idx]
    Y = fun(X)
    dY = Y[:, :n] - Y[:, n:] if difference is None else difference(Y[:, :n], Y[:, n:])
    return np.swapaxes(dY / step[:, :, None], -1, -2)


def batch_F(process: Any, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
    """Process Jacobians (N, n, n), or a shared (n, n) for a linear model, at x (N, n)."""
    fn = getattr(process, "jacobian_batch", None)
    if fn is not None:
        return fn(x, u, dt)
    N = x.shape[0]
    F0 = process.jacobian(x[0], u_of(u, 0), dt)
    if F0 is None:
        uu = None if u is None else (np.asarray(u)[:, None, :] if np.ndim(u) == 2 else u)
        return numerical_jacobian_batch(lambda X: process.f(X, uu, dt), x)
    if process.linear:                     # F independent of x (and of u)
        return np.asarray(F0, dtype=float)
    return np.stack([F0] + [process.jacobian(x[i], u_of(u, i), dt) for i in range(1, N)])


def batch_H(model: Any, x: np.ndarray) -> np.ndarray:
    """Measurement Jacobians (N, m, n) at x (N, n)."""
    fn = getattr(model, "jacobian_batch", None)
    if fn is not None:
        return fn(x)
    H0 = model.jacobian(x[0])
    if H0 is None:
        return numerical_jacobian_batch(model.h, x, model.residual)
    return np.stack([np.atleast_2d(H0)] + [np.atleast_2d(model.jacobian(x[i])) for i in range(1, x.shape[0])])


def batch_R(R: Any, m: int, N: int) -> np.ndarray:
    """Measurement covariance as (m, m) shared or (N, m, m) per filter, from a matrix, variances or a
    scalar (as the single filters' ``as_covariance``), or a stack of those."""
    R = np.asarray(R, dtype=float)
    if R.ndim == 3:
        if R.shape != (N, m, m):
            raise ValueError(f"measurement covariances R have shape {R.shape}, expected ({N}, {m}, {m})")
        return R
    if R.ndim == 2 and R.shape == (N, m) and R.shape != (m, m):
        return R[:, :, None] * np.eye(m)
    return as_covariance(R, m)


def batch_H_rows(fn, x: np.ndarray) -> np.ndarray:
    """``fn(x_i)`` for each row of x (N, n), stacked: the per-filter fallback of a model's batched method
    for a rarely used part (e.g. a range lever arm)."""
    return np.stack([fn(xi) for xi in x])


#: Elements (points x n) of one block of :func:`propagate_cf`: a model's temporaries then stay in cache.
#: Measured on the 16-state ins over 1000 filters x 33 points (CPU ms a call of all blocks): 1024 points
#: 6.5, 2048 6.0, 4096 5.3, 8192 9.2, one block 16.6; the points-first blocks it replaced took 14.5.
CF_BLOCK = 65536


def propagate_cf(process: Any, X: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
    """``process.f`` on sigma points stored component-first, X (n, N, p) (fusion.batch.linalg
    ``sigma_points_cf``), with ``u`` None, (m,) shared or (N, m) per filter; returns (n, N, p).

    Why component-first: a vectorised model (ins) reads its state as rows, ``x.reshape(-1, n).T``; given
    points-first states (N, p, n) those rows are strided and its output is transposed back by a copy. Here
    each block is passed as the transpose of contiguous rows, so the model's rows are contiguous and its
    (M, n) result is a view of its own (n, M) array: 2.7x less time for the ins (CF_BLOCK), the same
    numbers (f is evaluated point by point). No change to the model itself."""
    n, N, p = X.shape
    M = N * p
    Xf = X.reshape(n, M)
    U = None
    if u is not None:
        u = np.asarray(u, dtype=float)
        if u.ndim == 2:
            U = np.repeat(u.T, p, axis=1)                 # (m, M): each filter's input at its points
    Y = np.empty((n, M))
    step = max(1, CF_BLOCK // n)
    for a in range(0, M, step):
        b = min(M, a + step)
        ub = u if U is None else U[:, a:b].T
        Y[:, a:b] = np.asarray(process.f(Xf[:, a:b].T, ub, dt)).T
    return Y.reshape(n, N, p)
