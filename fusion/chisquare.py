"""Chi-square distribution functions in plain Python: ``chi2.ppf(p, k)``, ``chi2.isf(q, k)``, ``chi2.cdf(x, k)``,
``chi2.sf(x, k)``.

Written here rather than taken from scipy because of start-up: a run asks for a handful of quantiles
(gate thresholds, the consistency bounds), and importing scipy.special for them cost ~45-70 ms of the
headline command's ~1 s (scipy.stats 1-1.5 s). The results agree with scipy.stats.chi2 to ~1e-13
relative (tests check it over dof 1 .. 10^5 and both tails).

The regularised incomplete gamma functions P(a, x) and Q(a, x) (chi-square(k): a = k/2 at x/2) are
computed as in Numerical Recipes (the series below x < a + 1, Lentz's continued fraction above) with
the prefactor x^a e^-x / Gamma(a) in a form that stays accurate for large a (Stirling's series and
log1p, so a NEES sum over thousands of steps keeps its digits). The quantile is a safeguarded Newton
iteration from the Wilson-Hilferty approximation, on whichever tail is the smaller.
"""
from __future__ import annotations

import math
from statistics import NormalDist

__all__ = ["chi2", "isf_log"]

_EPS = 2.220446049250313e-16
_TINY = 1e-300
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


def _stirling_error(a: float) -> float:
    """ln Gamma(a) - ((a - 1/2) ln a - a + ln sqrt(2 pi)) (the remainder of Stirling's formula), by its
    asymptotic series: for a >= 15, where :func:`_prefactor` uses it, the terms kept reach 1e-17."""
    r = 1.0 / (a * a)
    return (1.0 / 12.0 - r * (1.0 / 360.0 - r * (1.0 / 1260.0 - r * (1.0 / 1680.0 - r / 1188.0)))) / a


def _prefactor(a: float, x: float) -> float:
    """x^a e^-x / Gamma(a), computed without cancelling for large a:
    a ln x - x - ln Gamma(a) = a (ln(x/a) + 1 - x/a) + ln sqrt(a / 2 pi) - stirling_error(a)."""
    if a < 15.0 or not -0.5 < (x - a) / a < 1.0:  # direct form: accurate here (or the value underflows)
        return math.exp(a * math.log(x) - x - math.lgamma(a))
    t = (x - a) / a
    return math.exp(a * (math.log1p(t) - t) + 0.5 * math.log(a) - _LOG_SQRT_2PI - _stirling_error(a))


def _series_p(a: float, x: float) -> float:
    """P(a, x) by its power series (x < a + 1): x^a e^-x / Gamma(a + 1) * sum x^n / ((a+1)...(a+n))."""
    return _series(a, x) * _prefactor(a, x)


def _series(a: float, x: float) -> float:
    """The power series of P(a, x) (x < a + 1), P = prefactor * it."""
    term = total = 1.0 / a
    n = a
    for _ in range(100_000):
        n += 1.0
        term *= x / n
        total += term
        if abs(term) < abs(total) * _EPS:
            break
    return total


def _log_prefactor(a: float, x: float) -> float:
    """ln(x^a e^-x / Gamma(a)): :func:`_prefactor` before its exp (for tails beyond the float range)."""
    if a < 15.0 or not -0.5 < (x - a) / a < 1.0:
        return a * math.log(x) - x - math.lgamma(a)
    t = (x - a) / a
    return a * (math.log1p(t) - t) + 0.5 * math.log(a) - _LOG_SQRT_2PI - _stirling_error(a)


def _fraction_q(a: float, x: float) -> float:
    """Q(a, x) by its continued fraction (x >= a + 1), modified Lentz."""
    return _prefactor(a, x) * _fraction(a, x)


def _fraction(a: float, x: float) -> float:
    """The continued fraction of Q(a, x) (x >= a + 1), Q = prefactor * it, modified Lentz."""
    b = x + 1.0 - a
    c = 1.0 / _TINY
    d = 1.0 / b
    h = d
    for i in range(1, 100_000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        if abs(d) < _TINY:
            d = _TINY
        c = b + an / c
        if abs(c) < _TINY:
            c = _TINY
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _EPS:
            break
    return h


def _p_q(a: float, x: float) -> tuple[float, float]:
    """(P(a, x), Q(a, x)), each computed directly where it is the smaller one."""
    if x <= 0.0:
        return 0.0, 1.0
    if math.isinf(x):
        return 1.0, 0.0
    if x < a + 1.0:
        p = _series_p(a, x)
        return p, 1.0 - p
    q = _fraction_q(a, x)
    return 1.0 - q, q


def _check_dof(k: float) -> float:
    k = float(k)
    if not k > 0.0 or math.isinf(k):
        raise ValueError(f"chi-square degrees of freedom must be positive and finite, got {k}")
    return k


def _cdf(x: float, k: float) -> float:
    return _p_q(0.5 * _check_dof(k), 0.5 * float(x))[0]


def _sf(x: float, k: float) -> float:
    return _p_q(0.5 * _check_dof(k), 0.5 * float(x))[1]


def _ppf(p: float, k: float) -> float:
    k = _check_dof(k)
    p = float(p)
    if not 0.0 <= p <= 1.0:
        return math.nan
    if p == 0.0:
        return 0.0
    if p == 1.0:
        return math.inf
    upper = p > 0.5            # solve on the smaller tail: Q(a, y) = 1 - p, else P(a, y) = p
    if not upper and p < _P_LOG_LOWER:
        return _ppf_lower_log(math.log(p), k)
    return _quantile(1.0 - p if upper else p, k, upper, NormalDist().inv_cdf(p))


def _ppf_lower_log(log_p: float, k: float) -> float:
    """x with ln P(X <= x) = ``log_p`` far in the lower tail (p < 1e-20), by Newton on ln P(k/2, y) in
    u = ln y, whose slope is 1 / S (S the power series, P = prefactor S): Newton on P itself crawls there,
    and the start y = (p Gamma(a + 1))^(1/a) underflows for small dof. 0.0 when the quantile is below the
    smallest float."""
    a = 0.5 * k
    u = (log_p + math.lgamma(a + 1.0)) / a                 # ln y: P ~ y^a / Gamma(a + 1) as y -> 0
    for _ in range(200):
        if u < -745.0:                                     # exp(u) is below the smallest subnormal
            return 0.0
        y = math.exp(u)
        if y >= a + 1.0:                                   # not the far lower tail after all
            return _quantile(math.exp(log_p), k, False, NormalDist().inv_cdf(math.exp(log_p)))
        series = _series(a, y)
        g = _log_prefactor(a, y) + math.log(series) - log_p
        u_new = u - g * series
        if abs(u_new - u) <= 4.0 * _EPS:
            u = u_new
            break
        u = u_new
    return 2.0 * math.exp(u)


def _isf(q: float, k: float) -> float:
    """x with P(X > x) = q, solved on the upper tail itself when q is small (1 - q rounds to 1 below
    q ~ 1e-16, where ``ppf(1 - q)`` would be inf: a gate far out in the tail)."""
    k = _check_dof(k)
    q = float(q)
    if not 0.0 <= q <= 1.0:
        return math.nan
    if q == 0.0:
        return math.inf
    if q == 1.0:
        return 0.0
    if q >= 0.5:
        return _ppf(1.0 - q, k)
    if q < _Q_LOG:
        return _isf_newton_log(math.log(q), k)
    return _quantile(q, k, True, -NormalDist().inv_cdf(q))


def _quantile(target: float, k: float, upper: bool, z: float) -> float:
    """Solve Q(k/2, y) = target (``upper``) or P(k/2, y) = target for x = 2 y; ``z`` the standard normal
    quantile of the same probability (the start)."""
    a = 0.5 * k
    # Start: Wilson-Hilferty, or the small-x limit P ~ y^a / Gamma(a + 1) far in the lower tail.
    h = 2.0 / (9.0 * k)
    y = 0.5 * k * max(1.0 - h + z * math.sqrt(h), 0.0) ** 3
    if y <= 0.0:
        y = math.exp((math.log(target) + math.lgamma(a + 1.0)) / a)
    lo, hi = 0.0, math.inf
    for _ in range(200):
        pp, qq = _p_q(a, y)
        f = (qq - target) if upper else (pp - target)   # decreasing in y (upper), increasing (lower)
        if f == 0.0:
            break
        if (f > 0.0) == upper:
            lo = y
        else:
            hi = y
        density = _prefactor(a, y) / y                   # dP/dy
        y_new = (y + f / density if upper else y - f / density) if 0.0 < density < math.inf else math.nan
        if abs(y_new - y) <= 4.0 * _EPS * y:              # converged (to the last few ulps)
            y = y_new
            break
        if not lo < y_new < hi:                           # outside the bracket (or no slope): bisect, or grow
            y_new = 0.5 * (lo + hi) if math.isfinite(hi) else max(2.0 * y, y + 1.0)
        y = y_new
    return 2.0 * y


def _logsf(x: float, k: float) -> float:
    """ln P(X > x), finite where P(X > x) itself underflows (x beyond ~1400 for small k)."""
    a, y = 0.5 * _check_dof(k), 0.5 * float(x)
    if y < a + 1.0 or math.isinf(y):
        q = _p_q(a, y)[1]
        return math.log(q) if q > 0.0 else -math.inf
    return _log_prefactor(a, y) + math.log(_fraction(a, y))


# Below this upper-tail probability the quantile is solved on ln Q: Newton on Q itself crawls there (Q changes
# by e per unit of y, so each step moves y by about one) and the probability underflows beyond ~1e-308
_Q_LOG = 1e-30
_LOG_Q_LOG = math.log(_Q_LOG)
_P_LOG_LOWER = 1e-20      # the same for the lower tail (Newton on P loses its way from ~1e-30 at 30 dof)


def isf_log(log_q: float, k: float) -> float:
    """x with ln P(X > x) = ``log_q`` for X ~ chi-square(k): the upper-tail quantile where the probability
    itself is below the float range (an n-sigma gate at n > ~37). Newton on ln Q(k/2, y), whose slope is
    -1 / (y F) with F the continued fraction (Q = prefactor F)."""
    k = _check_dof(k)
    log_q = float(log_q)
    if log_q != log_q or log_q > 0.0:
        return math.nan
    if log_q == -math.inf:
        return math.inf
    if log_q >= _LOG_Q_LOG:
        return _isf(math.exp(log_q), k)
    return _isf_newton_log(log_q, k)


def _isf_newton_log(log_q: float, k: float) -> float:
    a = 0.5 * k
    y = max(-log_q + (a - 1.0) * math.log(-log_q), a + 1.0)    # ln Q ~ (a - 1) ln y - y - ln Gamma(a)
    for _ in range(200):
        frac = _fraction(a, y)
        g = _log_prefactor(a, y) + math.log(frac) - log_q   # decreasing in y
        y_new = max(y + g * y * frac, 0.5 * (y + a + 1.0))
        if abs(y_new - y) <= 4.0 * _EPS * y:
            y = y_new
            break
        y = y_new
    return 2.0 * y


def _map(fn, first, k):
    """Apply ``fn`` elementwise when either argument is an array (numpy is imported only then)."""
    if isinstance(first, (int, float)) and isinstance(k, (int, float)):
        return fn(first, k)
    import numpy as np

    fa, ka = np.broadcast_arrays(np.asarray(first, dtype=float), np.asarray(k, dtype=float))
    out = np.array([fn(f, kk) for f, kk in zip(fa.ravel().tolist(), ka.ravel().tolist())], dtype=float)
    return out.reshape(fa.shape) if fa.ndim else float(out[0])


class _Chi2:
    """scipy.stats.chi2's functions that a run needs, with its argument order: ``(value, dof)``."""

    @staticmethod
    def ppf(p, k):
        """Quantile: x with P(X <= x) = p for X ~ chi-square(k)."""
        return _map(_ppf, p, k)

    @staticmethod
    def cdf(x, k):
        """P(X <= x) for X ~ chi-square(k)."""
        return _map(_cdf, x, k)

    @staticmethod
    def isf(q, k):
        """Upper-tail quantile: x with P(X > x) = q (accurate where 1 - q rounds to 1)."""
        return _map(_isf, q, k)

    @staticmethod
    def logsf(x, k):
        """ln P(X > x), finite far beyond where ``sf`` underflows to 0."""
        return _map(_logsf, x, k)

    @staticmethod
    def sf(x, k):
        """P(X > x) for X ~ chi-square(k), accurate far in the upper tail."""
        return _map(_sf, x, k)


chi2 = _Chi2()
