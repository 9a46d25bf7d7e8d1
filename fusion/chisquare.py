"""Chi-square quantiles without importing scipy.stats (1-1.5 s at start-up) : scipy.special's cdtr family.

``chi2.ppf(p, k)``, ``chi2.cdf(x, k)`` and ``chi2.sf(x, k)`` agree with scipy.stats.chi2 (tests check it).
"""
from __future__ import annotations

from scipy.special import chdtr, chdtrc, chdtri


class _Chi2:
    @staticmethod
    def ppf(p, k):
        """Quantile: x with P(X <= x) = p for X ~ chi-square(k)."""
        return chdtri(k, 1.0 - p)

    @staticmethod
    def cdf(x, k):
        return chdtr(k, x)

    @staticmethod
    def sf(x, k):
        return chdtrc(k, x)


chi2 = _Chi2()
