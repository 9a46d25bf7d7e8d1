import numpy as np
import pytest
from scipy import stats

from fusion.chisquare import chi2


@pytest.mark.parametrize("k", [1, 2, 3, 4, 15, 16])
def test_matches_scipy_stats(k):
    p = np.array([1e-4, 0.025, 0.5, 0.95, 0.975, 0.999])
    np.testing.assert_allclose(chi2.ppf(p, k), stats.chi2.ppf(p, k), rtol=1e-10)
    x = np.array([0.01, 1.0, 5.0, 30.0])
    np.testing.assert_allclose(chi2.cdf(x, k), stats.chi2.cdf(x, k), rtol=1e-10)
    np.testing.assert_allclose(chi2.sf(x, k), stats.chi2.sf(x, k), rtol=1e-10)
