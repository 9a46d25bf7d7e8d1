"""Stacked dense linear algebra for batched filters: Cholesky with repair by mask, QR square roots,
symmetric solves. numpy's ``linalg`` gufuncs call LAPACK once per stack (potrf, geqrf, syevd, gesv)
from C: no Python loop over the N matrices.

:func:`cholesky` flags the matrices whose pivots fail (LAPACK dpotrf's test, as the single filters'
``cholesky_lower``) with a mask; the filters repair those together, the eigenvalues clipped as in
``plugins.filters.linalg.recover_factor`` (:func:`recover_factors`).
"""
from __future__ import annotations

import numpy as np

from fusion_plugins.filters.linalg import cholesky_lower

__all__ = ["sym", "T", "cholesky", "recover_factors", "qr_lower", "psd_sqrt_rows", "solve_spd", "mm",
           "sigma_points", "sigma_points_cf", "sigma_deviations"]


def T(A: np.ndarray) -> np.ndarray:
    """Transpose of the last two axes (a view)."""
    return np.swapaxes(A, -1, -2)


def sym(P: np.ndarray) -> np.ndarray:
    """(P + P^T) / 2 over a stack (..., n, n)."""
    return (P + T(P)) * 0.5


def recover_factors(P: np.ndarray, rel_floor: float = 1e-12) -> np.ndarray:
    """Lower factors (k, n, n) of the nearest positive-definite matrices to P (k, n, n): symmetrise,
    clip eigenvalues to ``max(rel_floor max|eig|, sqrt(tiny))``, re-factorise (as recover_factor).

    Raises FloatingPointError when a P holds NaN or inf."""
    P = sym(np.asarray(P, dtype=float))
    if not np.isfinite(P).all():
        raise FloatingPointError("covariance holds NaN or inf; cannot recover a positive-definite factor")
    w, V = np.linalg.eigh(P)
    floor = np.maximum(rel_floor * np.abs(w).max(axis=-1, keepdims=True), np.finfo(float).tiny ** 0.5)
    w = np.maximum(w, floor)
    return np.linalg.cholesky(sym((V * w[..., None, :]) @ T(V)))


def qr_lower(A: np.ndarray) -> np.ndarray:
    """Lower-triangular L (N, n, n), non-negative diagonal, with L L^T = A^T A for A (N, k, n), k >= n:
    the transposed R of the stacked economy QR (paper 000 Algorithm 1, ``qr{.}``)."""
    R = np.linalg.qr(A, mode="r")
    s = np.sign(np.diagonal(R, axis1=-2, axis2=-1))
    s = np.where(s == 0.0, 1.0, s)
    return T(R * s[..., :, None])


def psd_sqrt_rows(Q: np.ndarray) -> np.ndarray:
    """Row square roots B (..., n, n), B^T B = Q, of symmetric positive semi-definite Q (..., n, n):
    ``sqrt(max(w, 0)) V^T`` of the eigen-decomposition (valid for singular Q too). Any row square root
    gives the same QR factor downstream (to rounding)."""
    w, V = np.linalg.eigh(sym(Q))
    return np.sqrt(np.maximum(w, 0.0))[..., :, None] * T(V)


def solve_spd(S: np.ndarray, B: np.ndarray) -> np.ndarray:
    """S^-1 B for symmetric positive-definite S (N, m, m) and B (N, m, k); m = 1 as a division."""
    if S.shape[-1] == 1:
        return B / S
    return np.linalg.solve(S, B)


def mm(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A @ B over a stack where one side may be one shared matrix: then one BLAS gemm on the stack
    reshaped (N x (n, n) @ (n, n) as one (N n, n) @ (n, n)), far faster than N tiny products."""
    if A.ndim == 2 and B.ndim == 3:
        N, k, j = B.shape
        return np.swapaxes((np.swapaxes(B, -1, -2).reshape(N * j, k) @ A.T).reshape(N, j, A.shape[0]), -1, -2)
    if B.ndim == 2 and A.ndim == 3:
        N, i, k = A.shape
        return (A.reshape(N * i, k) @ B).reshape(N, i, B.shape[1])
    return A @ B


def cholesky(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lower Cholesky factors L (N, n, n) of P (N, n, n) read from the lower triangle, and ``ok`` (N,):
    False where a pivot is not > 0 (NaN included), LAPACK dpotrf's test, so the single filters and the
    batch flag the same matrices. For n <= 6 a column loop over all N at once (a Python loop over the
    n columns, never over filters; ~2x numpy's gufunc at n = 4); beyond, ``np.linalg.cholesky`` and, only
    when it fails, the per-matrix dpotrf verdicts. The factors of failed matrices are garbage."""
    N, n, _ = P.shape
    if n > 6:
        try:
            return np.linalg.cholesky(P), np.ones(N, bool)
        except np.linalg.LinAlgError:
            ok = np.array([cholesky_lower(np.asarray(p, order="F"))[1] for p in P])   # rare path only
            L = np.zeros_like(P)
            if ok.any():
                L[ok] = np.linalg.cholesky(P[ok])
            return L, ok
    Pt = np.ascontiguousarray(P.transpose(1, 2, 0))      # (n, n, N): every element a contiguous N-vector
    Lt = np.zeros((n, n, N))
    ok = np.ones(N, bool)
    for j in range(n):
        d = Pt[j, j] - (Lt[j, :j] ** 2).sum(axis=0) if j else Pt[j, j].copy()
        ok &= d > 0.0
        r = np.sqrt(np.where(d > 0.0, d, 1.0))
        Lt[j, j] = r
        if j + 1 < n:
            c = Pt[j + 1:, j] - (Lt[j + 1:, :j] * Lt[j, :j]).sum(axis=1) if j else Pt[j + 1:, j]
            Lt[j + 1:, j] = c / r
    return Lt.transpose(2, 0, 1), ok


def sigma_deviations(eta: float, L: np.ndarray) -> np.ndarray:
    """The sigma points' deviations (N, 2n+1, n) from the means, ``[0, +eta L_i, -eta L_i]`` (rows: the
    columns L_i of the factors L (N, n, n)); the same numbers as ``SigmaPoints.E @ L^T``, by copies."""
    N, n, _ = L.shape
    D = np.empty((N, 2 * n + 1, n))
    D[:, 0] = 0.0
    np.multiply(np.swapaxes(L, -1, -2), eta, out=D[:, 1:n + 1])
    np.negative(D[:, 1:n + 1], out=D[:, n + 1:])
    return D


def sigma_points(x: np.ndarray, eta: float, L: np.ndarray) -> np.ndarray:
    """The sigma points (N, 2n+1, n) ``[x, x + eta L_i, x - eta L_i]`` of means x (N, n) and factors L
    (N, n, n): ``x + sigma_deviations(eta, L)`` in one pass."""
    N, n = x.shape
    X = np.empty((N, 2 * n + 1, n))
    X[:, 0] = x
    D = np.multiply(np.swapaxes(L, -1, -2), eta)
    np.add(x[:, None, :], D, out=X[:, 1:n + 1])
    np.subtract(x[:, None, :], D, out=X[:, n + 1:])
    return X


def sigma_points_cf(x: np.ndarray, eta: float, L: np.ndarray) -> np.ndarray:
    """The sigma points of :func:`sigma_points` stored component-first, (n, N, 2n+1): element a of point i
    of filter k at [a, k, i] (the same numbers). A process model then sees each state element of all the
    points as one contiguous row (fusion.batch.models.propagate_cf)."""
    N, n = x.shape
    X = np.empty((n, N, 2 * n + 1))
    xt = x.T
    X[:, :, 0] = xt
    D = np.multiply(L.transpose(1, 0, 2), eta)          # D[a, k, i] = eta L[k, a, i]
    np.add(xt[:, :, None], D, out=X[:, :, 1:n + 1])
    np.subtract(xt[:, :, None], D, out=X[:, :, n + 1:])
    return X
