"""A position fix from ranges with an honest covariance, and consensus outlier rejection (not a component).

Used by ``ols_trilateration``. The linear OLS of paper 000 (eqs. 25-32) gives the starting point; this
module refines it to the weighted least-squares fix of the range equations (eq. 17) and states what the
fix is worth:

* **range noise and geometry**: ranges r_i = |x - B_i| + e_i with e ~ N(0, Sigma_r); Gauss-Newton on the
  whitened equations, J the unit lines of sight, ``cov = (J^T Sigma_r^-1 J)^-1``;
* **compensation uncertainty**: range i was taken dt_i after the fix time and referred to it with a
  velocity v of covariance P_v (the filter's, plus unmodelled receiver velocity) and an unmodelled
  acceleration a ~ N(0, s_a^2 I): ``Sigma_r = s_r^2 I + G P_v G^T + (s_a^2 / 4) H H^T`` with rows
  ``G_i = u_i^T dt_i`` and ``H_i = u_i^T (dt_i^2 - 2 age dt_i)`` (u_i the unit line of sight): the errors
  are shared between the ranges, so they are correlated, not extra independent noise. ``age`` (s): the
  velocity is the belief's ``age`` after the fix time, so it differs from the velocity at the fix time by
  ``a age``; the receiver moved ``v dt_i + a (dt_i^2 / 2 - age dt_i)`` more than assumed;
* **the known height** of the 2-D system (paper 000 sec. IV: z is not solved for): its error dz (sd z_sd)
  moves every range by ``u_z,i dz``, a range error shared by the cycle, so ``z_sd^2 u_z u_z^T`` joins
  Sigma_r and the fix covariance gets z_sd^2 on z and the cross terms; or (``solve_height``) z is
  estimated with the horizontal position under the prior ``z ~ N(z0, z_sd^2)`` (roof beacons, well
  above the receiver; near the beacons' plane the range is quadratic in z and that estimate biased);
* **residual misfit**: the covariance is scaled by ``max(1, chi2 / dof)`` (the a-posteriori variance factor
  of least squares), so a cycle that fits worse than its noise claims less.

Outliers (a reflected, longer path): the chi-square of the whitened residuals (``dof = k - unknowns``, the
height prior counted as an equation) tests a set of ranges. If the whole cycle fails, every subset with one
range fewer is solved and tested, then two fewer, ... (up to ``max_outliers``; all subsets are cheap at
k <= 12): the consistent subset with the smallest chi-square is kept. If two consistent subsets of that
size give fixes that disagree beyond their covariances, the data cannot tell which range is bad, and no
fix is given (``ambiguous``) rather than one that may have dropped a good range to keep a bad one; no
consistent subset at all gives no fix (``inconsistent``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from itertools import combinations
from typing import Callable

import numpy as np

from fusion.chisquare import chi2
from fusion.lapack import lapack

_dpotrf, _dpotrs, _dtrtrs = lapack.dpotrf, lapack.dpotrs, lapack.dtrtrs   # no argument checks


class NoFix(ValueError):
    """No fix from these ranges; ``reason``: too_few_beacons, degenerate, inconsistent or ambiguous."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


@lru_cache(maxsize=256)
def chi2_limit(probability: float, dof: int) -> float:
    """``chi2.ppf(probability, dof)`` (cached: chi2.ppf is slow)."""
    return float(chi2.ppf(probability, dof))


@dataclass
class Cycle:
    """The ranges of one cycle referred to one time: beacons B (k, 3) already shifted by ``-v dt`` (m),
    ranges r (k,) (m), offsets dt (k,) (s, range time minus fix time), the covariance P_v (3, 3) of the
    velocity used (m^2/s^2) and the unmodelled acceleration sd (m/s^2)."""

    B: np.ndarray
    r: np.ndarray
    dt: np.ndarray = field(default_factory=lambda: np.zeros(0))
    Pv: np.ndarray | None = None
    accel_sd: float = 0.0
    z_var: float = 0.0          # m^2: variance of an assumed (not solved-for) receiver height
    age: float = 0.0            # s: the velocity used is of this long after the fix time


@dataclass
class Fit:
    """A fix from the ranges ``used`` (indices into the cycle): position (3,), covariance (3, 3), chi-square
    of the whitened residuals with ``dof`` degrees of freedom, residuals (m) of the used ranges."""

    used: list[int]
    pos: np.ndarray
    cov: np.ndarray
    chi2: float
    dof: int
    residuals: np.ndarray
    info: dict = field(default_factory=dict)


def range_cov(U: np.ndarray, cyc: Cycle, idx: np.ndarray, sigma: float) -> np.ndarray:
    """Sigma_r (k, k) of the ranges ``idx`` at lines of sight U (k, 3): noise + compensation (module doc)."""
    k = len(idx)
    if cyc.Pv is not None and len(cyc.dt):
        dt = cyc.dt[idx]
        G = U * dt[:, None]
        S = G @ cyc.Pv @ G.T
        S.flat[::k + 1] += sigma * sigma
        if cyc.accel_sd:
            H = U * (dt * (dt - 2.0 * cyc.age))[:, None]
            S += (0.25 * cyc.accel_sd ** 2) * (H @ H.T)
    else:
        S = np.zeros((k, k))
        S.flat[::k + 1] = sigma * sigma
    if cyc.z_var:
        uz = U[:, 2]
        S += (cyc.z_var * uz)[:, None] * uz
    return S


_EYE = {k: np.eye(k) for k in range(1, 4)}


def _weights(U: np.ndarray, cyc: Cycle, idx: np.ndarray, sigma: float) -> np.ndarray:
    """Sigma_r^-1 (k, k) by Cholesky (dpotrs on the identity: at these sizes faster than dpotri + mirror)."""
    L, info = _dpotrf(range_cov(U, cyc, idx, sigma), lower=1)
    if info != 0:
        raise NoFix("degenerate", "range covariance not positive definite")
    return _dpotrs(L, np.eye(len(idx)), lower=1)[0]


def weighted_fix(cyc: Cycle, idx: np.ndarray, x0: np.ndarray, *, dim: int, z: float, z_sd: float, sigma: float,
                 iterations: int) -> Fit:
    """Gauss-Newton from ``x0`` (3,) on the range equations of the ranges ``idx`` weighted by Sigma_r^-1 (and
    the height prior in 2-D when solving for it); the covariance ``(J^T Sigma_r^-1 J)^-1`` at the solution.

    Sigma_r is formed at the lines of sight of the start, again after a first step over 10 cm (a smaller
    step turns them by step / range, a negligible change of the covariance), and inverted by Cholesky:
    each pass is then a few small products.
    """
    B, r = cyc.B[idx], cyc.r[idx]
    prior = dim == 2 and z_sd > 0 and not cyc.z_var
    nu = 3 if (dim == 3 or prior) else 2
    x = x0.copy()
    if dim == 2 and not prior:
        x[2] = z
    wz = 1.0 / z_sd ** 2 if prior else 0.0
    d = x - B
    rho = np.sqrt((d * d).sum(axis=1))
    U = d / np.maximum(rho, 1e-12)[:, None]
    W = _weights(U, cyc, idx, sigma)
    it = 0
    while True:
        res = r - rho
        J = U[:, :nu]
        WJ = W @ J
        N = J.T @ WJ
        g = WJ.T @ res
        if prior:
            N[2, 2] += wz
            g[2] += (z - x[2]) * wz
        C, info = _dpotrf(N, lower=1)
        if info != 0:
            raise NoFix("degenerate", "the ranges do not determine the position (normal matrix singular)")
        if it >= iterations:
            break
        step = _dtrtrs(C, _dtrtrs(C, g, lower=1)[0], lower=1, trans=1)[0]   # N^-1 g by the Cholesky factor
        s2 = float(step @ step)
        if s2 < 1e-6:
            # converged (a step under 1 mm): the linearisation at x holds at x + step to O(step^2 / range),
            # under a micrometre, so the residuals and the covariance are those of this pass, moved along it
            x[:nu] += step
            res = res - J @ step
            break
        if s2 > 1e-4:
            # step halving: in a weak geometry a full Gauss-Newton step of centimetres or more can overshoot
            cost = float(res @ W @ res) + (x[2] - z) ** 2 * wz
            for _ in range(8):
                xn = x.copy()
                xn[:nu] += step
                dn = xn - B
                rn = r - np.sqrt((dn * dn).sum(axis=1))
                if float(rn @ W @ rn) + (xn[2] - z) ** 2 * wz <= cost * (1.0 + 1e-12):
                    break
                step = 0.5 * step
        x[:nu] += step
        it += 1
        d = x - B
        rho = np.sqrt((d * d).sum(axis=1))
        U = d / np.maximum(rho, 1e-12)[:, None]
        if it == 1 and s2 > 1e-2:       # moved over 10 cm from the start: the weights at the new sight lines
            W = _weights(U, cyc, idx, sigma)
    stat = float(res @ W @ res) + (x[2] - z) ** 2 * wz
    Ninv = _dpotrs(C, _EYE[nu], lower=1)[0]
    cov = np.zeros((3, 3))
    cov[:nu, :nu] = Ninv
    if dim == 2 and not prior:
        x[2] = z
        if cyc.z_var:           # the assumed height's error: var z_var, and its pull on the horizontal fix
            cov[2, 2] = cyc.z_var
            Ku = Ninv @ (WJ.T @ U[:, 2])
            cov[:2, 2] = cov[2, :2] = -cyc.z_var * Ku
    dof = len(idx) + (1 if prior else 0) - nu
    return Fit(idx.tolist(), x, cov, stat, dof, res)


def consensus(k: int, solve: Callable[[np.ndarray], Fit], *, probability: float | None, max_outliers: int,
              min_beacons: int, fix_dof: int) -> tuple[Fit, list[int]]:
    """The fix of the largest consistent subset of a cycle's ``k`` ranges (module doc); returns it and the
    rejected indices. ``solve(idx) -> Fit`` fixes from the ranges ``idx`` (may raise NoFix); ``fix_dof`` is
    the number of position coordinates a fix determines (for the ambiguity test between two fixes).

    :raises NoFix: ``inconsistent`` (no subset of at least ``min_beacons`` ranges with at most
        ``max_outliers`` dropped is consistent) or ``ambiguous`` (two consistent subsets disagree).
    """
    full = solve(np.arange(k))
    if probability is None or full.dof < 1 or full.chi2 <= chi2_limit(probability, full.dof):
        return full, []
    for drop in range(1, max_outliers + 1):
        m = k - drop
        if m < min_beacons:
            break
        good: list[Fit] = []
        for sub in combinations(range(k), m):
            try:
                f = solve(np.array(sub))
            except NoFix:
                continue
            if f.dof >= 1 and f.chi2 <= chi2_limit(probability, f.dof):
                good.append(f)
        if not good:
            continue
        best = min(good, key=lambda f: f.chi2)
        lim = chi2_limit(probability, fix_dof)
        for f in good:
            if f is best:
                continue
            d = f.pos - best.pos
            C = f.cov + best.cov
            keep = np.flatnonzero(np.diag(C) > 0)
            dd = d[keep]
            if float(dd @ np.linalg.solve(C[np.ix_(keep, keep)], dd)) > lim:
                dropped = sorted(set(range(k)) - set(best.used))
                other = sorted(set(range(k)) - set(f.used))
                raise NoFix("ambiguous", f"dropping range(s) {dropped} or {other} both fit, with fixes "
                            f"{np.linalg.norm(d[:2]):.2f} m apart")
        return best, sorted(set(range(k)) - set(best.used))
    raise NoFix("inconsistent", f"range residuals chi2 = {full.chi2:.1f} with {full.dof} dof (limit "
                f"{chi2_limit(probability, full.dof):.1f}, residuals {np.round(full.residuals, 3).tolist()} m) "
                f"and no consistent subset with up to {max_outliers} range(s) dropped")


def inflate(fit: Fit) -> np.ndarray:
    """The fix covariance scaled by the a-posteriori variance factor ``max(1, chi2 / dof)``."""
    if fit.dof < 1:
        return fit.cov
    return fit.cov * max(1.0, fit.chi2 / fit.dof)
