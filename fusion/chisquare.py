"""Chi-square quantiles without importing scipy.stats (1-1.5 s at start-up) : scipy.special's cdtr family.

``chi2.ppf(p, k)``, ``chi2.cdf(x, k)`` and ``chi2.sf(x, k)`` agree with scipy.stats.chi2 (tests check it).
"""
from __future__ import annotations



class _Chi2:
    # scipy.special is imported at the first call, not at start-up (~45 ms): a gate or a consistency
    # statistic asks for a quantile once, when it is built or first used.
    @staticmethod
    def ppf(p, k):
        """Quantile: x with P(X <= x) = p for X ~ chi-square(k)."""
        from scipy.special import chdtri

        return chdtri(k, 1.0 - p)

    @staticmethod
    def cdf(x, k):
        from scipy.special import chdtr

        return chdtr(k, x)

    @staticmethod
    def sf(x, k):
        from scipy.special import chdtrc

        return chdtrc(k, x)


chi2 = _Chi2()
