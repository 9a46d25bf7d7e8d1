"""Monte-Carlo consistency (Bar-Shalom): 50 seeded runs; the NEES averaged over the runs is chi-square
with 50 n degrees of freedom (divided by 50) at every step when the filter is consistent."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from fusion import testing

RUNS, STEPS, DT = 50, 80, 0.1
BEACONS = [[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0]]


def _nees_runs(name, meas, R, params=None, R_filter=None):
    proc = testing.ConstantVelocity(testing.ConstantVelocity.Params(q=0.5))
    P0 = np.diag([0.5, 0.5, 0.2, 0.2])
    nees = np.empty((RUNS, STEPS))
    for run in range(RUNS):
        rng = np.random.default_rng(1000 + run)
        flt = testing.build("filter", name, params)
        x = np.array([6.0, 5.0, 1.0, 0.5])
        b = flt.initial_belief(0.0, x + rng.multivariate_normal(np.zeros(4), P0), P0)
        for k in range(STEPS):
            x = proc.f(x, None, DT) + rng.multivariate_normal(np.zeros(4), proc.Q(x, None, DT))
            z = meas.h(x) + rng.multivariate_normal(np.zeros(meas.dim), R)
            b = flt.update(flt.predict(b, proc, None, DT), meas, z, R if R_filter is None else R_filter).belief
            nees[run, k] = testing.nees(x, b)
    return nees


def _check(nees, n=4):
    lo, hi = chi2.ppf([0.025, 0.975], RUNS * n) / RUNS
    per_step = nees.mean(axis=0)
    inside = float(np.mean((per_step >= lo) & (per_step <= hi)))
    return per_step.mean(), inside, (lo, hi)


def test_kf_is_consistent_on_linear_model():
    meas = testing.PositionMeasurement()
    mean, inside, (lo, hi) = _check(_nees_runs("kf", meas, np.diag([0.05, 0.08])))
    assert lo <= mean <= hi, (mean, lo, hi)
    assert inside >= 0.85


def test_ukf_is_consistent_on_range_model():
    meas = testing.RangeMeasurement(testing.RangeMeasurement.Params(beacons=BEACONS))
    mean, inside, (lo, hi) = _check(_nees_runs("ukf", meas, np.eye(4) * 0.1 ** 2))
    assert lo <= mean <= hi, (mean, lo, hi)
    assert inside >= 0.85


def test_the_check_can_fail():
    """An overconfident filter (its R four times too small) fails the same check."""
    meas = testing.PositionMeasurement()
    R = np.diag([0.05, 0.08])
    mean, inside, (lo, hi) = _check(_nees_runs("kf", meas, R, R_filter=R / 4.0))
    assert not (lo <= mean <= hi and inside >= 0.85)
