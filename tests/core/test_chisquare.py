"""fusion.chisquare: scipy.stats.chi2's numbers (the same scipy.special calls) without importing scipy.stats;
its far upper tail (beyond the float range of the probability) against the closed forms of integer dof."""
import math
import subprocess
import sys

import numpy as np
import pytest
from scipy import stats

from fusion.chisquare import chi2

TAILS = np.array([1e-12, 1e-6, 1e-4, 0.001, 0.01, 0.025, 0.05, 0.1, 0.3, 0.5, 0.7, 0.9, 0.95, 0.975, 0.99,
                  0.999, 0.9999, 1 - 1e-9])
# Small dof (gates: 1-4), a state's (15, 16, 22), and NEES / NIS sums over a run (up to 10^5).
DOFS = [0.5, 1, 2, 3, 4, 5, 9, 15, 16, 22, 29, 30, 31, 100, 1000, 5100, 75000, 100000]


@pytest.mark.parametrize("k", DOFS)
def test_quantiles_are_scipys(k):
    np.testing.assert_array_equal(chi2.ppf(TAILS, k), stats.chi2.ppf(TAILS, k))
    np.testing.assert_array_equal(chi2.isf(TAILS, k), stats.chi2.isf(TAILS, k))


@pytest.mark.parametrize("k", DOFS)
def test_cdf_and_sf_match_scipy_in_both_tails(k):
    x = np.concatenate([stats.chi2.ppf(TAILS, k), [0.01, 1.0, 5.0, 30.0, float(k)]])
    for ours, ref in ((chi2.cdf, stats.chi2.cdf), (chi2.sf, stats.chi2.sf)):
        want = ref(x, k)
        keep = want > 1e-290  # not underflowed
        np.testing.assert_allclose(np.asarray(ours(x, k))[keep], want[keep], rtol=2e-11)


def test_quantile_inverts_cdf_on_a_dense_grid():
    rng = np.random.default_rng(7)
    for k in rng.uniform(0.3, 400, 40):
        for p in rng.uniform(0, 1, 10):
            assert chi2.cdf(chi2.ppf(p, k), k) == pytest.approx(p, rel=1e-12, abs=1e-15)


def test_scalars_give_floats_and_edges():
    assert isinstance(chi2.ppf(0.95, 3), float)
    assert chi2.ppf(0.0, 3) == 0.0 and chi2.ppf(1.0, 3) == math.inf
    assert math.isnan(chi2.ppf(1.5, 3))
    assert chi2.cdf(0.0, 2) == 0.0 and chi2.sf(0.0, 2) == 1.0
    assert chi2.cdf(math.inf, 2) == 1.0
    assert chi2.cdf(2.0, 2) == pytest.approx(1 - math.exp(-1.0), rel=1e-15)  # closed form for k = 2
    with pytest.raises(ValueError, match="degrees of freedom"):
        chi2.ppf(0.5, 0)
    shaped = chi2.ppf(np.full((2, 3), 0.5), 4)
    assert shaped.shape == (2, 3)


def test_does_not_import_scipy_stats():
    code = ("import sys, fusion.chisquare as c; c.chi2.ppf(0.99, 3); c.chi2.sf(9.0, 2); c.isf_log(-1e3, 3); "
            "print('scipy.stats' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def _log_q_closed_form(k: int, y: float) -> float:
    """ln Q(k/2, y) by the closed forms of integer k (a finite sum for even k; erfc plus a sum for odd k),
    with scipy's log_ndtr for the erfc: independent of the continued fraction under test."""
    from scipy.special import log_ndtr

    if k % 2 == 0:
        return -y + float(np.logaddexp.reduce([j * math.log(y) - math.lgamma(j + 1) for j in range(k // 2)]))
    terms = [math.log(2.0) + float(log_ndtr(-math.sqrt(2.0 * y)))]
    terms += [-y + (j + 0.5) * math.log(y) - math.lgamma(j + 1.5) for j in range((k - 1) // 2)]
    return float(np.logaddexp.reduce(terms))


@pytest.mark.parametrize("k", [1, 2, 3, 4, 6, 9, 15])
def test_logsf_far_beyond_the_float_range_of_sf(k):
    for x in (10.0, 100.0, 1400.0, 3000.0, 1e5, 1e6):
        assert chi2.logsf(x, k) == pytest.approx(_log_q_closed_form(k, 0.5 * x), rel=1e-13)
    assert chi2.logsf(30.0, k) == pytest.approx(float(stats.chi2.logsf(30.0, k)), rel=1e-12)


@pytest.mark.parametrize("k", [1, 2, 3, 4, 6, 9, 15])
def test_upper_tail_quantiles(k):
    from fusion.chisquare import isf_log

    for q in (0.5, 0.1, 1e-6, 1e-17, 1e-100, 1e-280):  # 1e-17: ppf(1 - q) would be inf (1 - q rounds to 1)
        want = float(stats.chi2.isf(q, k))
        assert chi2.isf(q, k) == pytest.approx(want, rel=1e-12)
        assert isf_log(math.log(q), k) == pytest.approx(want, rel=1e-12)
    for log_q in (-800.0, -1e4, -5e5):                 # probabilities that underflow: against the closed form
        x = isf_log(log_q, k)
        assert _log_q_closed_form(k, 0.5 * x) == pytest.approx(log_q, rel=1e-13)
    assert chi2.isf(0.0, k) == math.inf and chi2.isf(1.0, k) == 0.0 and math.isnan(chi2.isf(1.5, k))


@pytest.mark.parametrize("k", [0.5, 1, 2, 3, 5, 10, 30, 103, 500, 1000, 10_000, 100_000])
def test_far_lower_tail_quantiles(k):
    """p down to 1e-300: Newton on P itself went astray from ~1e-30 (ppf(1e-100, 103) was 1.6e124, ppf(1e-200,
    1) a bare ValueError; tester4 #8); solved on ln P there."""
    p = np.array([1e-15, 1e-21, 1e-30, 1e-50, 1e-100, 1e-200, 1e-300])
    np.testing.assert_allclose(chi2.ppf(p, k), stats.chi2.ppf(p, k), rtol=1e-12)


@pytest.mark.parametrize("k", [1, 2, 3, 4, 6, 9, 15])
def test_far_tail_closed_form_meets_scipy_where_both_are_floats(k):
    """The closed form fusion.chisquare uses below 1e-300 against scipy's own sf just above: an independent
    check of the formula the far-tail tests above share with the code."""
    from fusion.chisquare import _log_q_integer

    for q in (1e-200, 1e-250, 1e-290):
        x = float(stats.chi2.isf(q, k))
        assert _log_q_integer(k, x) == pytest.approx(math.log(stats.chi2.sf(x, k)), rel=1e-12)
