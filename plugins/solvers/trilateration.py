"""Trilateration, the pure part of ``ols_trilateration`` (paper 000 sec. IV, eqs. 17-32): one position fix
with its covariance from ranges to known beacons (:func:`trilaterate`), and the packing of a fix as the
numbers of a recording's fix line (:func:`pack_fix`, :func:`unpack_fix`). No state, no messages: the
component that gathers firing cycles and emits typed fixes is plugins/solvers/ols_trilateration.py."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from fusion_plugins.solvers.ols_linear import condition, ols_fit, solve_linear
from fusion_plugins.solvers.range_fix import Cycle, Fit, NoFix, consensus, inflate, weighted_fix

__all__ = ["trilaterate", "pack_fix", "unpack_fix"]


def trilaterate(beacons: np.ndarray, ranges: np.ndarray, *, dim: int = 3, z: float = 0.0, z_sd: float = 0.0,
                sigma: float = 1.0, reference: str | int = "nearest", qr_condition: float = 1e6,
                degenerate_condition: float = 1e12, refine: int = 0, consistency_probability: float | None = None,
                max_outliers: int = 1, min_beacons: int | None = None, offsets: np.ndarray | None = None,
                velocity_cov: np.ndarray | None = None, accel_sd: float = 0.0, solve_height: bool = False,
                inflate_misfit: bool = False, start: np.ndarray | None = None,
                velocity_age: float = 0.0) -> tuple[np.ndarray, np.ndarray, dict]:
    """One position fix from ranges to known beacons (paper 000 eqs. 17-32), with outlier rejection.

    :param beacons: (k, 3) beacon positions (m, navigation frame; (k, 2) is padded with ``z``), already
        shifted by ``-v dt`` when the ranges were referred to one time (motion compensation).
    :param ranges: (k,) measured ranges (m).
    :param dim: 3 (x, y, z from the ranges, k >= 4 non-coplanar) or 2 (the mine case: the receiver height
        ``z`` is known to ``z_sd``, k >= 3 non-collinear beacons).
    :param sigma: range noise sd (m).
    :param reference: the reference beacon of eq. 25: ``nearest`` (shortest range), ``first`` (the paper's
        B1) or an index.
    :param qr_condition: above this cond(A^T A) the QR path (A = QR, R x = Q^T b) replaces the normal
        equations of eq. 32; above ``degenerate_condition`` there is no fix (``degenerate``).
    :param refine: Gauss-Newton iterations on the whitened range equations (eq. 17) after the OLS fix
        (0: the paper's OLS, with its first-order covariance). With ``refine`` > 0 in 2-D the height's
        uncertainty ``z_sd`` is part of the range covariance, or (``solve_height``) the height is
        estimated too, with the prior z ~ N(z, z_sd^2) (plugins/solvers/range_fix.py).
    :param offsets: (k,) s, time of each range minus the fix time; with ``velocity_cov`` (3, 3) (m^2/s^2)
        and ``accel_sd`` (m/s^2) the uncertainty of referring the ranges to the fix time, as correlated
        range errors.
    :param velocity_age: s, how long after the fix time the velocity that referred the ranges is (its
        difference from the velocity at the fix time, ``accel_sd`` x age, joins the acceleration term).
    :param consistency_probability: if set, the chi-square test of the whitened residuals; a failed cycle
        gives the largest consistent subset (consensus, up to ``max_outliers`` dropped, at least
        ``min_beacons`` kept) or no fix (``inconsistent`` / ``ambiguous``).
    :param inflate_misfit: scale the covariance by max(1, chi2 / dof).
    :param start: (3,) m, where Gauss-Newton starts (``refine`` > 0) instead of the OLS fix, e.g. the last
        fix moved by the velocity (the OLS test of eq. 28's geometry still applies).
    :returns: ``(position (3,), covariance (3, 3), info)``; ``info``: ``method`` (ols/qr[+gauss-newton]),
        ``cond`` (of A^T A), ``reference``, ``residuals`` (m, of the used ranges), ``chi2``, ``dof``,
        ``used`` and ``rejected`` (indices into the input).
    :raises NoFix: with ``reason`` too_few_beacons, degenerate, inconsistent or ambiguous.
    """
    B = np.asarray(beacons, dtype=float)
    r = np.asarray(ranges, dtype=float)
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim}")
    if B.ndim != 2 or B.shape[1] not in (2, 3) or r.shape != (B.shape[0],):
        raise ValueError(f"expected beacons (k, 3) and ranges (k,), got {B.shape} and {r.shape}")
    if B.shape[1] == 2:
        B = np.column_stack([B, np.full(len(B), z)])
    if not (np.isfinite(B.sum()) and np.isfinite(r.sum())):     # one reduction each (a nan or inf propagates)
        raise ValueError("beacons and ranges must be finite")
    k = len(r)
    if k < dim + 1:
        raise NoFix("too_few_beacons", f"{k} range(s), a {dim}-D fix needs at least {dim + 1}")
    dt = np.zeros(k) if offsets is None else np.asarray(offsets, dtype=float)
    cyc = Cycle(B, r, dt, None if velocity_cov is None else np.asarray(velocity_cov, dtype=float), accel_sd,
                z_sd ** 2 if (dim == 2 and refine and not solve_height) else 0.0, float(velocity_age))
    lin = (dim, z, z_sd, sigma, reference, qr_condition, degenerate_condition)

    def solve(idx: np.ndarray) -> Fit:
        if not refine:
            return ols_fit(cyc, idx, *lin)
        Bi, ri = cyc.B[idx], cyc.r[idx]
        ref = int(np.argmin(ri)) if reference == "nearest" else 0
        if start is None:                                     # the paper's OLS is the start
            pos0, _, info = solve_linear(Bi, ri, dim, z, ref, qr_condition, degenerate_condition, gain=False)
        else:                                                 # a start given: only eq. 28's geometry test
            D = np.delete(Bi, ref, axis=0) - Bi[ref]
            pos0, info = np.asarray(start, dtype=float), {"method": "start",
                                                          "cond": condition(D, dim, degenerate_condition)}
        g = weighted_fix(cyc, idx, pos0, dim=dim, z=z, z_sd=z_sd, sigma=sigma, iterations=refine)
        g.info = {**info, "method": info["method"] + "+gauss-newton", "reference": int(idx[ref])}
        return g

    fit, rejected = consensus(k, solve, probability=consistency_probability, max_outliers=max_outliers,
                              min_beacons=max(dim + 1, min_beacons or 0),
                              fix_dof=3 if dim == 3 or (refine and z_sd > 0 and solve_height) else 2)
    cov = inflate(fit) if inflate_misfit else fit.cov
    info = {**fit.info, "residuals": fit.residuals, "chi2": fit.chi2, "dof": fit.dof, "used": fit.used,
            "rejected": rejected}
    return fit.pos, 0.5 * (cov + cov.T), info


_IU3 = np.triu_indices(3)


def pack_fix(position: np.ndarray, covariance: np.ndarray) -> tuple[float, ...]:
    """Message values of a fix: ``x y z cxx cxy cxz cyy cyz czz`` (m, m^2; the upper triangle)."""
    return tuple(np.concatenate([position, covariance[_IU3]]).tolist())


def unpack_fix(values: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`pack_fix`: position (3,) and covariance (3, 3)."""
    v = np.asarray(values, dtype=float)
    cov = np.zeros((3, 3))
    cov[np.triu_indices(3)] = v[3:9]
    cov = cov + np.triu(cov, 1).T
    return v[:3], cov
