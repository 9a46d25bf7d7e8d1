"""The batch fix of a standing robot from every arrival so far (paper 003 eqs. 1, 11): what the initialiser
of ``tdoa_geometric`` hands the filter when the robot is known to stand still (``initialise_stationary``).

While the initialiser waits for three consecutive cycles whose fixes agree (an echo in a cycle of four
cannot be seen in that cycle), every earlier cycle is thrown away, with its genuine arrivals: at 12 %
echoes a wait of 10-40 cycles, a third of a static run of the paper's Tables I-II, and the filter's sd
ends that much above the bound of the run's arrivals. A standing robot's arrivals all fit one position and
one firing clock, ``a_j = t0 + n_j T + |p - b_j| / c`` (T known), so once the agreeing fixes give a
position, every earlier arrival can be tested against it and the consistent ones (the echoes are late by
0.3-3 m, 4-40 sd) fixed together by Gauss-Newton on [p, t0]. The fix's covariance is the inverse of their
information, ``sigma^2 (J^T J)^-1``, so the filter that starts from it ends at the bound of every arrival
it was given.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import cho_factor, cho_solve


def stationary_fix(beacons: np.ndarray, arrivals: np.ndarray, period: float, c: float, sigma: float,
                   start: np.ndarray, start_cov: np.ndarray | None = None, n_sigma: float = 2.0,
                   iterations: int = 8) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """Batch fix of a standing robot from arrivals ``arrivals`` (k,) (s) of beacons ``beacons`` (k, 3) (m).

    Firing counts ``n_j = round((a_j - a_0) / T)``; from ``start`` (3,) m, repeat: residuals
    ``r_j = a_j - n_j T - |p - b_j| / c``, keep the arrivals within ``n_sigma`` sd of t0 (their median at
    first; echoes are late), one Gauss-Newton step on [p, t0] over the kept ones. The sd is ``sigma`` (s),
    on the first pass with the start's uncertainty ``start_cov`` (3, 3) (m^2) projected on each line of
    sight, ``sqrt(sigma^2 + u^T C u / c^2)``.

    :returns: position (3,) m, t0 (s, the firing time of count 0), covariance (4, 4) of [p, t0]
        (m^2, m s, s^2) and the mask (k,) of the arrivals used.
    :raises numpy.linalg.LinAlgError: when the kept arrivals do not determine [p, t0].
    """
    p, t0, _, cov, keep = _batch(beacons, arrivals, period, c, sigma, start, start_cov, n_sigma, iterations, False)
    return p, t0, cov, keep


def stationary_period_fix(beacons: np.ndarray, arrivals: np.ndarray, period: float, c: float, sigma: float,
                          start: np.ndarray, start_cov: np.ndarray | None = None, n_sigma: float = 2.0,
                          iterations: int = 8) -> tuple[np.ndarray, float, float, np.ndarray, np.ndarray]:
    """:func:`stationary_fix` with the period free: Gauss-Newton on [p, t0, T] from T = ``period`` (s, which
    also counts the firings), so that a period a little off its nominal value neither biases the fix nor,
    through the trend ``n_j dT`` of the residuals, drops the genuine arrivals far from the middle.

    :returns: position (3,) m, t0 (s), T (s), covariance (5, 5) of [p, t0, T] and the mask of the arrivals
        used."""
    return _batch(beacons, arrivals, period, c, sigma, start, start_cov, n_sigma, iterations, True)


def _batch(beacons, arrivals, period, c, sigma, start, start_cov, n_sigma, iterations, fit_period):
    B = np.asarray(beacons, float)
    a = np.asarray(arrivals, float)
    n = np.rint((a - a[0]) / period)
    p = np.asarray(start, float).copy()
    keep = np.ones(a.size, bool)
    t0 = float(np.median(a - n * period - np.linalg.norm(p - B, axis=1) / c))
    m = 5 if fit_period else 4
    for it in range(iterations):
        d = p - B
        rng = np.linalg.norm(d, axis=1)
        r = a - n * period - rng / c
        sd = sigma
        if it == 0 and start_cov is not None:
            u = d / rng[:, None]
            sd = np.sqrt(sigma ** 2 + np.einsum("ki,ij,kj->k", u, np.asarray(start_cov, float), u) / c ** 2)
            t0 = float(np.median(r))
        keep = np.abs(r - t0) <= n_sigma * sd
        cols = [d / (c * rng[:, None]), np.ones(a.size)] + ([n] if fit_period else [])
        J = np.column_stack(cols)[keep]
        F = cho_factor(J.T @ J, lower=True)
        step = cho_solve(F, J.T @ (r[keep] - t0))
        p, t0 = p + step[:3], t0 + step[3]
        if fit_period:
            period = period + step[4]
        if np.abs(step[:3]).max() < 1e-7:
            break
    d = p - B
    cols = [d / (c * np.linalg.norm(d, axis=1)[:, None]), np.ones(a.size)] + ([n] if fit_period else [])
    J = np.column_stack(cols)[keep]
    cov = sigma ** 2 * cho_solve(cho_factor(J.T @ J, lower=True), np.eye(m))
    return p, t0, float(period), 0.5 * (cov + cov.T), keep


def period_fix(beacons: np.ndarray, arrivals: np.ndarray, period: float, c: float, sigma: float,
               start: np.ndarray, iterations: int = 8) -> tuple[np.ndarray, float, float, np.ndarray]:
    """Batch fix of ``[p, t0, T]`` from the arrivals of a few consecutive cycles (paper 003 eq. 1 with the
    period free, the model of :func:`fusion_plugins.solvers.tdoa_geometric.stationary_bound`):
    ``a_j = t0 + n_j T + |p - b_j| / c``, firing counts ``n_j = round((a_j - a_0) / period)`` from the nominal
    ``period`` (s; right while the counts are fewer than ``0.5 / relative error``, 100 firings at 0.5 %),
    by Gauss-Newton from ``start`` (3,) m and T = ``period``, every arrival kept (the cycles agreed).

    The beacons' period is a resonator's, known to a tolerance (+-0.5 % for a ceramic one): fixed at its
    nominal value a 0.2 % error moves a four-beacon fix by ~0.5 m (c n T / 1000 over the 3 firings of a
    cycle) while every cycle agrees with the next. Three cycles fix T to ~20 us.

    :param beacons: (k, 3) m; ``arrivals``: (k,) s; ``c`` m/s; ``sigma`` arrival sd (s).
    :returns: position (3,) m, t0 (s, the firing time of count 0), T (s) and the covariance (5, 5) of
        ``[p, t0, T]`` (``sigma^2 (J^T J)^-1``, m^2, m s, s^2).
    :raises numpy.linalg.LinAlgError: when the arrivals cannot determine the five (fewer than 5, one beacon).
    """
    B = np.asarray(beacons, float)
    a0 = float(np.asarray(arrivals, float)[0])
    a = np.asarray(arrivals, float) - a0         # relative: t0 of a Unix-time log is ~1e9 s
    n = np.rint(a / period)
    p = np.asarray(start, float).copy()
    T = float(period)
    t0 = float(np.median(a - n * T - np.linalg.norm(p - B, axis=1) / c))
    for _ in range(iterations):
        d = p - B
        rng = np.linalg.norm(d, axis=1)
        r = a - t0 - n * T - rng / c
        J = np.column_stack([d / (c * rng[:, None]), np.ones(a.size), n])
        step = cho_solve(cho_factor(J.T @ J, lower=True), J.T @ r)
        p, t0, T = p + step[:3], t0 + step[3], T + step[4]
        if np.abs(step[:3]).max() < 1e-7:
            break
    d = p - B
    J = np.column_stack([d / (c * np.linalg.norm(d, axis=1)[:, None]), np.ones(a.size), n])
    info = J.T @ J
    w = np.linalg.eigvalsh(info)
    if not np.all(np.isfinite(w)) or w[0] <= 1e-12 * w[-1]:
        raise np.linalg.LinAlgError("period_fix: the arrivals do not determine [p, t0, T]")
    cov = sigma ** 2 * cho_solve(cho_factor(info, lower=True), np.eye(5))
    return p, t0 + a0, T, 0.5 * (cov + cov.T)
