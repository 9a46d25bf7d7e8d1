"""The chi-square functions a run needs (gate thresholds, consistency bounds): ``chi2.ppf(p, k)``,
``chi2.isf(q, k)``, ``chi2.cdf(x, k)``, ``chi2.sf(x, k)``, ``chi2.logsf(x, k)`` and :func:`isf_log`.

They are the functions of ``scipy.special`` that ``scipy.stats.chi2`` itself calls (``2 gammaincinv(k/2, p)``,
``chdtri``, ``chdtr``, ``chdtrc``), so the numbers are scipy.stats.chi2's to the bit, without importing
scipy.stats (~0.45 s, a third of ``fusion run``'s process); scipy.special is imported on the first call.

What scipy lacks is the upper tail beyond the float range: an n-sigma gate on a vector at n > ~37 needs the
quantile of a probability below 1e-308. For integer k (a measurement's dimension) ln P(X > x) has a closed
form, used there: ``e^-y sum_{j<k/2} y^j / j!`` for even k, ``2 Phi(-sqrt(2y)) + e^-y sum_{j<(k-1)/2}
y^(j+1/2) / Gamma(j+3/2)`` for odd k (y = x/2, scipy's ``log_ndtr`` for the Phi term).
"""
from __future__ import annotations

import math

__all__ = ["chi2", "isf_log"]

#: below this upper-tail probability the far-tail closed form is used (the smallest normal float is ~2.2e-308)
_Q_FLOOR = 1e-300
_LOG_Q_FLOOR = math.log(_Q_FLOOR)


def _sc():
    import scipy.special

    return scipy.special


def _float(v):
    """A numpy scalar or 0-d result as a Python float; arrays as they are."""
    return float(v) if getattr(v, "ndim", 0) == 0 else v


def _check_dof(k):
    kk = k if isinstance(k, (int, float)) else min(getattr(k, "flat", [k]))
    if not kk > 0:
        raise ValueError(f"chi-square degrees of freedom must be > 0, got {k}")


def _log_q_integer(k: int, x: float) -> float:
    """ln P(X > x) for X ~ chi-square(k), k a positive integer, by the closed forms above (finite far beyond
    the float range of the probability)."""
    y = 0.5 * x
    if k % 2 == 0:
        terms = [j * math.log(y) - math.lgamma(j + 1) for j in range(k // 2)]
        base = -y
    else:
        terms = [math.log(2.0) + float(_sc().log_ndtr(-math.sqrt(x))) + y]
        terms += [(j + 0.5) * math.log(y) - math.lgamma(j + 1.5) for j in range((k - 1) // 2)]
        base = -y
    top = max(terms)
    return base + top + math.log(sum(math.exp(t - top) for t in terms))


def _integer_dof(k) -> int:
    if float(k) != int(k):
        raise ValueError(f"the far upper tail (probability below {_Q_FLOOR:g}) needs an integer dof, got {k}")
    return int(k)


class _Chi2:
    """scipy.stats.chi2's functions that a run needs, with its argument order: ``(value, dof)``."""

    @staticmethod
    def ppf(p, k):
        """Quantile: x with P(X <= x) = p for X ~ chi-square(k)."""
        _check_dof(k)
        return _float(2.0 * _sc().gammaincinv(0.5 * k if isinstance(k, (int, float)) else k / 2, p))

    @staticmethod
    def cdf(x, k):
        """P(X <= x) for X ~ chi-square(k)."""
        _check_dof(k)
        return _float(_sc().chdtr(k, x))

    @staticmethod
    def sf(x, k):
        """P(X > x) for X ~ chi-square(k)."""
        _check_dof(k)
        return _float(_sc().chdtrc(k, x))

    @staticmethod
    def isf(q, k):
        """Upper-tail quantile: x with P(X > x) = q (accurate where 1 - q rounds to 1)."""
        _check_dof(k)
        return _float(_sc().chdtri(k, q))

    @staticmethod
    def logsf(x: float, k: float) -> float:
        """ln P(X > x) for scalars, finite far beyond where ``sf`` underflows (integer k there)."""
        q = chi2.sf(float(x), k)
        if q >= _Q_FLOOR or math.isnan(q) or math.isinf(x):
            return math.log(q) if q > 0.0 else -math.inf
        return _log_q_integer(_integer_dof(k), float(x))


chi2 = _Chi2()


def isf_log(log_q: float, k: float) -> float:
    """x with ln P(X > x) = ``log_q`` for X ~ chi-square(k): the upper-tail quantile also where the
    probability is below the float range (an n-sigma gate at n > ~37; integer k there), by Newton on the
    closed form of ln Q (its slope -pdf / Q)."""
    _check_dof(k)
    log_q = float(log_q)
    if log_q != log_q or log_q > 0.0:
        return math.nan
    if log_q == -math.inf:
        return math.inf
    if log_q >= _LOG_Q_FLOOR:
        return float(_sc().chdtri(k, math.exp(log_q)))
    kk = _integer_dof(k)
    x = float(_sc().chdtri(kk, _Q_FLOOR))               # start where the probability is still a float
    for _ in range(200):
        log_q_x = _log_q_integer(kk, x)
        log_pdf = (0.5 * kk - 1.0) * math.log(x) - 0.5 * x - 0.5 * kk * math.log(2.0) - math.lgamma(0.5 * kk)
        x_new = x + (log_q_x - log_q) / math.exp(log_pdf - log_q_x)   # d ln Q / dx = -pdf / Q
        if abs(x_new - x) <= 4e-16 * x:
            return x_new
        x = x_new
    return x
