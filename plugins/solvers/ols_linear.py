"""The paper's linear OLS trilateration (paper 000 eqs. 25-32; not a component): used by ``ols_trilateration``
as its fix (``refine_iterations: 0``) or as the start of the weighted Gauss-Newton fix (range_fix.py)."""
from __future__ import annotations

import math

import numpy as np

from fusion.lapack import lapack
from fusion_plugins.solvers.range_fix import Cycle, Fit, NoFix, range_cov

_dpotrf, _dpotrs, _dtrtrs = lapack.dpotrf, lapack.dpotrs, lapack.dtrtrs   # no argument checks


def condition(D: np.ndarray, dim: int, degenerate_condition: float) -> float:
    """cond(A^T A) of eq. 28 (A = D[:, :dim], the beacons relative to the reference); raises NoFix
    ``degenerate`` above ``degenerate_condition`` (collinear beacons in 2-D, coplanar in 3-D)."""
    A = D[:, :dim]
    AtA = A.T @ A
    if dim == 2:                       # eigenvalues of the symmetric 2 x 2 A^T A in closed form (cheaper than an SVD)
        h = 0.5 * (AtA[0, 0] + AtA[1, 1])
        e = math.sqrt(max(h * h - (AtA[0, 0] * AtA[1, 1] - AtA[0, 1] * AtA[1, 0]), 0.0))
        lo, hi = h - e, h + e
        cond = np.inf if lo <= hi * 1e-300 else hi / lo                  # cond(A^T A)
    else:
        sv = np.linalg.svd(A, compute_uv=False)
        cond = np.inf if sv[-1] <= sv[0] * 1e-300 else float((sv[0] / sv[-1]) ** 2)
    if not cond <= degenerate_condition:
        raise NoFix("degenerate", f"cond(A^T A) = {cond:.3g} > {degenerate_condition:.3g}: beacons "
                    f"{'collinear' if dim == 2 else 'coplanar'} or too close together")
    return cond


def solve_linear(B: np.ndarray, r: np.ndarray, dim: int, z: float, ref: int,
                  qr_condition: float, degenerate_condition: float,
                  gain: bool = True) -> tuple[np.ndarray, np.ndarray | None, dict]:
    """OLS/QR solution of eqs. 25-32 with beacon ``ref`` as the reference point; returns the position (3,),
    the gain G (dim, k) from ranges to position (first order; None without ``gain``) and info."""
    k = len(r)
    others = [i for i in range(k) if i != ref]
    D = B[others] - B[ref]                                    # B_i - B_ref (k-1, 3)
    A = D[:, :dim]                                            # eq. 28 (the factor 2 moved into b, eq. 25)
    b = 0.5 * (r[ref] ** 2 - r[others] ** 2 + (D * D).sum(axis=1))        # eqs. 25-26, 30
    if dim == 2:
        b = b - D[:, 2] * (z - B[ref, 2])                     # known height: its term moves to b
    AtA = A.T @ A
    cond = condition(D, dim, degenerate_condition)
    M = None
    if cond <= qr_condition:                                  # eq. 32 by Cholesky of the normal equations
        c, info = _dpotrf(AtA, lower=1)                        # LAPACK directly, without scipy's checking wrappers
        if info == 0:
            M = _dpotrs(c, A.T, lower=1)[0]
            method = "ols"
    if M is None:                                             # A = QR, R x = Q^T b by back substitution
        from scipy.linalg import qr, solve_triangular         # rare (ill-conditioned): not at start-up
        Qm, Rm = qr(A, mode="economic", check_finite=False)
        M = solve_triangular(Rm, Qm.T, check_finite=False)    # (A^T A)^-1 A^T without forming A^T A
        method = "qr"
    xrel = M @ b                                              # eq. 29: x - x_ref
    pos = B[ref].copy()
    pos[:dim] += xrel
    if dim == 2:
        pos[2] = z
    if not gain:
        return pos, None, {"method": method, "cond": cond}
    # First order: db_i = r_ref dr_ref - r_i dr_i (r at the fix, less noisy than measured)
    dB = pos - B
    d_fix = np.sqrt((dB * dB).sum(axis=1))
    Jb = np.zeros((k - 1, k))
    Jb[:, ref] = d_fix[ref]
    Jb[np.arange(k - 1), others] = -d_fix[others]
    return pos, M @ Jb, {"method": method, "cond": cond}


def ols_fit(cyc: Cycle, idx: np.ndarray, dim: int, z: float, z_sd: float, sigma: float, reference: str | int,
             qr_condition: float, degenerate_condition: float) -> Fit:
    """The paper's OLS fix (eqs. 25-32) of the ranges ``idx`` with its first-order covariance
    ``G Sigma_r G^T`` (G = d position / d ranges through the linear model; Sigma_r as in range_fix)."""
    B, r = cyc.B[idx], cyc.r[idx]
    ref = int(np.argmin(r)) if reference == "nearest" else (0 if reference == "first" else
                                                            int(np.flatnonzero(idx == reference)[0])
                                                            if reference in idx else 0)
    pos, G, info = solve_linear(B, r, dim, z, ref, qr_condition, degenerate_condition)
    d = pos - B
    rho = np.sqrt(np.einsum("ij,ij->i", d, d))
    U = d / np.maximum(rho, 1e-12)[:, None]
    res = r - rho
    S = range_cov(U, cyc, idx, sigma)
    cov = np.zeros((3, 3))
    cov[:dim, :dim] = G @ S @ G.T
    if dim == 2:
        cov[2, 2] = z_sd ** 2
    L, ok = _dpotrf(S, lower=1)
    rw = _dtrtrs(L, res, lower=1)[0]
    info["reference"] = int(idx[ref])
    return Fit(list(map(int, idx)), pos, 0.5 * (cov + cov.T), float(rw @ rw), len(idx) - dim, res, info)
