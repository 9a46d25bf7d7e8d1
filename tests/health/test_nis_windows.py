"""The NIS window test of the health rule (fusion.health.rule.nis_windows_beyond) against chi-square
statistics: its thresholds are scipy's chi-square quantiles, its false-alarm rate over many seeded runs of
a consistent filter is the rate it is set to, and it finds an NIS persistently too large."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2 as sp_chi2

from fusion.health.rule import nis_windows_beyond


def _windows(rng, k: int, dof: int, scale: float = 1.0) -> list[tuple[float, float, float, int]]:
    """k windows of a consistent filter's NIS sums over ``dof`` dof (chi-square), times ``scale``."""
    sums = scale * rng.chisquare(dof, size=k)
    return [(float(i), float(i) + 1.0, float(s), dof) for i, s in enumerate(sums)]


def test_threshold_is_scipys_chi_square_quantile_at_the_bonferroni_tail():
    """A window just over scipy's isf((alpha/K)^(1/2), dof) is beyond, one just under is not (the run of two
    is what counts: two windows at the value)."""
    alpha, k, dof = 1e-3, 10, 100
    q = math.sqrt(alpha / k)
    cut = sp_chi2.isf(q, dof)
    base = [(0.0, 1.0, float(dof), dof)] * (k - 2)
    # fusion.chisquare agrees with scipy to ~1e-13 relative: 1e-9 relative either side is decided
    over = base + [(0.0, 1.0, cut * (1 + 1e-9), dof)] * 2
    under = base + [(0.0, 1.0, cut * (1 - 1e-9), dof)] * 2
    assert nis_windows_beyond(over, alpha)[1:] == (2, pytest.approx(q, rel=1e-12))
    assert nis_windows_beyond(under, alpha)[1] == 0


@pytest.mark.parametrize("k, dof", [(12, 100), (60, 100), (3, 105)])
def test_false_alarm_rate_over_many_seeded_consistent_runs(k, dof):
    """4,000 seeded runs of a consistent filter: flagged (two consecutive windows beyond) at about
    alpha (K - 1) / K, never above alpha. alpha is 0.05 here so the rate is measurable with 4,000 runs
    (binomial sd ~0.0034); the rule's default 1e-3 is the same construction."""
    alpha, runs = 0.05, 4000
    rng = np.random.default_rng(20261207 + k)
    flagged = sum(nis_windows_beyond(_windows(rng, k, dof), alpha)[1] >= 2 for _ in range(runs))
    rate = flagged / runs
    q = math.sqrt(alpha / k)
    # P(some two consecutive of K independent windows beyond) = 1 - P(no run of 2), about (K-1) q^2
    expected = (k - 1) * q * q - (k - 2) * q ** 3
    sd = math.sqrt(expected * (1 - expected) / runs)
    assert abs(rate - expected) < 4 * sd, (rate, expected)
    assert rate < alpha + 4 * sd


def test_default_rate_on_consistent_runs_is_below_one_in_a_thousand():
    """20,000 seeded consistent runs of 30 windows at the default alpha 1e-3: flagged about
    20,000 x 1e-3 x 29/30 = 19.3 times in expectation; 34 is the Poisson(19.3) 99.9 % quantile."""
    rng = np.random.default_rng(28)
    k, dof, runs = 30, 100, 20000
    sums = rng.chisquare(dof, size=(runs, k))
    q = math.sqrt(1e-3 / k)
    beyond = sums > sp_chi2.isf(q, dof)
    pairs = (beyond[:, 1:] & beyond[:, :-1]).any(axis=1)
    assert pairs.sum() <= 34
    # the rule itself on the first 300 of them agrees with this vectorised reference
    for i in range(300):
        w = [(0.0, 1.0, float(s), dof) for s in sums[i]]
        assert (nis_windows_beyond(w, 1e-3)[1] >= 2) == bool(pairs[i])


@pytest.mark.parametrize("scale", [2.0, 3.0])
def test_an_nis_persistently_too_large_is_found(scale):
    """A filter whose innovations are sqrt(scale) times what it predicts (NIS x scale): flagged in every one
    of 200 seeded runs of 12 windows (the quantile at q ~ 0.009 on 100 dof is 1.36 per dof)."""
    rng = np.random.default_rng(5)
    assert all(nis_windows_beyond(_windows(rng, 12, 100, scale), 1e-3)[1] >= 2 for _ in range(200))


def test_no_window_and_one_window():
    assert nis_windows_beyond([], 1e-3)[1] == 0
    one = [(0.0, 1.0, 1000.0, 100)]
    assert nis_windows_beyond(one, 1e-3)[1] == 1   # a run of one window is tested at alpha itself


def test_a_mild_inconsistency_is_significant_but_not_far_outside():
    """NIS 1.5 per dof (sd 0.21 per dof over 100 dof): mostly beyond the chi-square quantile (1.36 per dof
    here), so flagged without a floor, never with the rule's default floor of 2 per dof; 2.5 per dof is."""
    rng = np.random.default_rng(8)
    mild = _windows(rng, 12, 100, 1.5)
    assert nis_windows_beyond(mild, 1e-3)[1] >= 2                  # flagged: two in a row beyond
    assert nis_windows_beyond(mild, 1e-3, min_ratio=2.0)[1] == 0
    assert nis_windows_beyond(_windows(rng, 12, 100, 2.5), 1e-3, min_ratio=2.0)[1] >= 2
