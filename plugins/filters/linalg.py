"""Small dense linear algebra for the filters: Cholesky, QR-based square roots, rank-1 up/downdates.

Matrices here are tiny (n <= ~20), so the time goes to Python and per-call overhead, not to flops
(DESIGN.md "Performance notes"). Hence:

* LAPACK is called directly (``scipy.linalg.lapack.dpotrf/dpotrs/dtrtrs/dgeqrfp``): ~2 us a call
  against 10-30 us for ``scipy.linalg.cho_factor``/``solve_triangular``/``qr`` with their checks.
* Triangular masks are cached per size (``np.triu`` alone costs ~10 us).
* The rank-1 Cholesky update/downdate is written without a Python loop over columns (see
  :func:`cholupdate`); we write our own because neither numpy nor scipy ships one.

Conventions: ``L`` is lower triangular with ``P = L L^T``; a "row square root" ``B`` of a PSD matrix
``Q`` satisfies ``B^T B = Q`` (rows are stacked under the weighted deviations before a QR).
No function here forms an explicit inverse.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import blas, lapack

__all__ = [
    "cholesky_lower", "robust_cholesky", "recover_factor", "psd_sqrt_rows", "qr_lower",
    "qr_lower_scaled", "cholupdate", "cho_solve_lower", "solve_lower", "symmetrise", "nis_from_factor",
]

_dpotrf = lapack.dpotrf
_dpotrs = lapack.dpotrs
_dtrtrs = lapack.dtrtrs
_dgeqrf = lapack.dgeqrf
_dgeqrfp = getattr(lapack, "dgeqrfp", None)   # LAPACK >= 3.3: R with a non-negative diagonal
_dsyevd = lapack.dsyevd
_dpstrf = lapack.dpstrf
_dtrsm = blas.dtrsm


_CONSTS: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}


def _consts(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cached (upper-triangular ones incl. diagonal, strictly-lower ones, flat diagonal indices)."""
    c = _CONSTS.get(n)
    if c is None:
        c = _CONSTS[n] = (np.triu(np.ones((n, n))), np.tril(np.ones((n, n)), -1), np.arange(n) * (n + 1))
    return c


def symmetrise(P: np.ndarray) -> np.ndarray:
    """(P + P^T) / 2."""
    return (P + P.T) * 0.5


def cholesky_lower(P: np.ndarray) -> tuple[np.ndarray, bool]:
    """Lower Cholesky factor of the (symmetric) P, read from its lower triangle; ``ok`` False when P is
    not numerically positive definite (then the factor is garbage and must not be used)."""
    L, info = _dpotrf(P, 1, 1)               # lower=1, clean=1 (positional: ~0.5 us less)
    return L, info == 0


def recover_factor(P: np.ndarray, rel_floor: float = 1e-12) -> np.ndarray:
    """Lower factor of the nearest positive-definite matrix to ``P``: symmetrise, clip eigenvalues to
    ``max(rel_floor * max|eig|, tiny)``, re-factorise. Used after a failed Cholesky or downdate.

    Raises FloatingPointError when P holds NaN or inf (nothing sensible can be recovered)."""
    P = symmetrise(np.asarray(P, dtype=float))
    if not np.isfinite(P).all():
        raise FloatingPointError("covariance holds NaN or inf; cannot recover a positive-definite factor")
    w, V, info = _dsyevd(P, compute_v=1, lower=1)
    if info != 0:  # pragma: no cover - LAPACK eigensolver failure on a finite symmetric matrix
        w, V = np.linalg.eigh(P)
    floor = max(rel_floor * float(np.abs(w).max(initial=0.0)), np.finfo(float).tiny ** 0.5)
    w = np.maximum(w, floor)
    Pc = (V * w) @ V.T
    L, ok = cholesky_lower(symmetrise(Pc))
    if not ok:  # clipped spectrum is PD by construction; rounding can still bite when w spans 1e16
        L = np.linalg.qr((V * np.sqrt(w)).T, mode="r")
        L = L.T * np.sign(np.diagonal(L))
    return L


def robust_cholesky(P: np.ndarray) -> tuple[np.ndarray, bool]:
    """Lower Cholesky factor of P; on failure the factor of the repaired P (:func:`recover_factor`).
    Returns ``(L, recovered)``: ``recovered`` True means P was not positive definite."""
    L, ok = cholesky_lower(P)
    if ok:
        return L, False
    return recover_factor(P), True


def psd_sqrt_rows(Q: np.ndarray) -> np.ndarray:
    """A row square root ``B`` (n, n) with ``B^T B = Q`` for a symmetric positive semi-definite Q.

    Cholesky when Q is definite; for a singular Q (a process noise with nothing along some direction,
    e.g. the norm of a quaternion) the pivoted Cholesky (LAPACK dpstrf, ~3 us) with the rows past the
    numerical rank set to 0, ``B = U P^T``; the eigen-decomposition (negative rounding clipped to 0)
    only if that fails."""
    L, ok = cholesky_lower(Q)
    if ok:
        return L.T
    U, piv, rank, info = _dpstrf(Q, lower=0)
    if info >= 0 and rank > 0:
        n = Q.shape[0]
        U = U * _consts(n)[0]                  # the upper triangle (LAPACK leaves input data below it)
        U[rank:] = 0.0                         # the trailing block is the unfactored remainder (~0)
        B = np.empty_like(U)
        B[:, piv - 1] = U
        if np.isfinite(B).all():
            return B
    w, V, _ = _dsyevd(symmetrise(np.asarray(Q, dtype=float)), compute_v=1, lower=1)
    return np.sqrt(np.maximum(w, 0.0))[:, None] * V.T


def qr_lower(A: np.ndarray, overwrite: bool = False) -> np.ndarray:
    """Lower-triangular ``L`` (n, n) with ``L L^T = A^T A`` for ``A`` (k, n), k >= n: the transposed R
    factor of the economy QR of A (paper 000 Algorithm 1, ``qr{.}``), diagonal made non-negative.

    Fastest with a Fortran-ordered A the caller lets us overwrite (``overwrite=True``): no copy; the
    workspace is given (the default makes LAPACK query it first, a second call)."""
    n = A.shape[1]
    if _dgeqrfp is not None:
        # dgeqrfp: Householder reflections chosen so that R has a non-negative diagonal, at the cost of
        # dgeqrf; then only the upper triangle is kept (below it LAPACK stores the Householder vectors):
        # one product with the cached mask, ~1.5 us less than fixing the signs afterwards
        R = _dgeqrfp(A, n, int(overwrite))[0][:n]   # lwork=n: unblocked, fastest when small
        return (R * _consts(n)[0]).T
    R = _dgeqrf(A, lwork=n, overwrite_a=int(overwrite))[0][:n]
    # keep the upper triangle, flip rows to a non-negative diagonal: one product with the sign-carrying mask
    return (R * np.copysign(_consts(n)[0], R.diagonal()[:, None])).T


_MASKS: dict[tuple[int, float], np.ndarray] = {}


def qr_lower_scaled(A: np.ndarray, scale: float) -> np.ndarray:
    """``qr_lower(scale * A)`` for a Fortran-ordered A it may overwrite, with the scaling applied to the
    (n, n) triangle instead of to A (folded into the cached triangular mask): the same factor to
    rounding, one strided multiply fewer when A is assembled from blocks."""
    n = A.shape[1]
    key = (n, scale)
    mask = _MASKS.get(key)
    if mask is None:
        if len(_MASKS) > 64:
            _MASKS.clear()
        mask = _MASKS[key] = _consts(n)[0] * abs(scale)
    if _dgeqrfp is None:  # pragma: no cover - LAPACK < 3.3
        return qr_lower(A, overwrite=True) * abs(scale)
    return (_dgeqrfp(A, n, 1)[0][:n] * mask).T


def cholupdate(L: np.ndarray, v: np.ndarray, weight: float = 1.0) -> tuple[np.ndarray, bool]:
    """Rank-1 Cholesky update (weight > 0) or downdate (weight < 0): lower ``L1`` with
    ``L1 L1^T = L L^T + weight v v^T`` (paper 000 Algorithm 1, ``cholupdate{S, v, weight}``).

    Vectorised form of the product method (Gill, Golub, Murray & Saunders 1974, method C1) instead of
    the usual loop of Givens/hyperbolic rotations over the columns. With ``p = L^{-1} v``,
    ``L L^T + w v v^T = L (I + w p p^T) L^T``, and the Cholesky factor ``M`` of ``I + w p p^T`` is
    known in closed form: with ``t_1 = 1/w`` and ``t_{j+1} = t_j + p_j^2`` (a cumulative sum),

        M_jj = sqrt(t_{j+1} / t_j),   M_ij = p_i p_j / (t_j M_jj)  (i > j),   M_ij = 0 (i < j)

    so ``L1 = L M`` costs one triangular solve, one cumulative sum (a product with a triangle of
    ones) and a handful of element-wise products: ~10 numpy calls whatever n, against 20-90 us for the
    loop over columns at n = 4-16.

    Returns ``(L1, ok)``; ``ok`` is False when the result would not be positive definite (a downdate
    removing more than there is: some ``t_{j+1} / t_j <= 0``) or not finite. Then ``L1`` must not be
    used: recover with :func:`recover_factor` of ``L L^T + w v v^T``.
    """
    p, info = _dtrtrs(L, v, lower=1)
    if info != 0:
        return L, False
    U1, SL, diag = _consts(p.shape[0])
    wp = weight * p
    wp2 = wp * p
    sn = wp2 @ U1                  # w t_{j+1} = 1 + w sum_{i<=j} p_i^2   (scaled by w: no 1/w overflow)
    sn += 1.0
    if not sn.min() > 0.0:         # w t_1 = 1 > 0, so every ratio t_{j+1}/t_j > 0 iff every w t_{j+1} > 0;
        return L, False            # also false for NaN
    sp = sn - wp2                  # w t_j
    d = np.sqrt(sn / sp)
    M = p[:, None] * (wp / (sp * d))
    M *= SL
    M.flat[diag] = d
    return L @ M, True            # finite: NaN/inf in L or v would have made some ratio NaN


def cho_solve_lower(L: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Solve ``(L L^T) X = B`` by two triangular solves (LAPACK dpotrs)."""
    return _dpotrs(L, B, lower=1)[0]


def solve_lower(L: np.ndarray, b: np.ndarray, trans: int = 0) -> np.ndarray:
    """Solve ``L X = B`` (``trans=1``: ``L^T X = B``) for lower-triangular L; B (m,) or (m, k).

    A vector goes to LAPACK dtrtrs, a matrix to BLAS dtrsm. Not dtrtrs for a matrix: OpenBLAS
    replaces it by a threaded version with no small-size cut-off, and after any numpy matmul (numpy
    ships its own OpenBLAS, whose idle threads spin) one 4x4 solve took ~8 ms instead of ~1 us on a
    2-core machine (measured; benchmarks/README.md)."""
    if b.ndim == 1:
        return _dtrtrs(L, b, 1, trans)[0]          # lower=1 (f2py parses positional arguments faster)
    return _dtrsm(1.0, L, b, 0, 1, trans)           # side=0 (left), lower=1, trans_a


def nis_from_factor(L: np.ndarray, y: np.ndarray) -> float:
    """Normalised innovation squared ``y^T (L L^T)^{-1} y = |L^{-1} y|^2``."""
    w = _dtrtrs(L, y, 1)[0]
    return float(w @ w)
