"""chi2 gate: thresholds from scipy.stats.chi2, n-sigma for scalars, rejection leaves the belief
untouched and is counted by the run's GateRun (the gate itself keeps nothing)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError
from scipy.stats import chi2

from fusion import testing
from fusion.api import GateDecision, GateRun


def _gate(**params):
    return testing.build("gate", "chi2", params)


@pytest.mark.parametrize("p", [0.9, 0.95, 0.997])
@pytest.mark.parametrize("dim", [1, 2, 3, 4, 7])
def test_threshold_is_chi2_ppf(p, dim):
    g = _gate(probability=p)
    th = chi2.ppf(p, dim)
    assert g.threshold(dim) == pytest.approx(th, rel=1e-12)
    assert g.accept(th * (1 - 1e-9), dim) and not g.accept(th * (1 + 1e-9), dim)
    decision, state = g.check(th * 0.5, dim)
    assert decision == GateDecision(True, pytest.approx(th)) and state is None


def test_default_probability():
    assert _gate().params.probability == 0.997


@pytest.mark.parametrize("n", [2.0, 3.0])
def test_n_sigma_on_scalars(n):
    g = _gate(n_sigma=n)
    S = 0.04                                   # innovation variance, sd 0.2
    for y, ok in ((0.99 * n * 0.2, True), (1.01 * n * 0.2, False), (-1.01 * n * 0.2, False)):
        assert g.accept(y * y / S, 1) is ok
    # in m dimensions: the chi-square quantile of the same probability as +-n sigma in 1-D
    assert g.threshold(3) == pytest.approx(chi2.ppf(chi2.cdf(n * n, 1), 3))


def test_counts_and_nan():
    g = _gate(probability=0.95)
    before = dict(vars(g))
    run = GateRun(g)
    results = [run.accept(v, 2) for v in (0.5, 100.0, 1.0, 5.9, float("nan"))]
    assert results == [True, False, True, True, False]
    assert run.counters == {"checked": 5, "rejected": 2}
    assert run.last == GateDecision(False, pytest.approx(chi2.ppf(0.95, 2)))
    assert vars(g) == before                   # the gate itself is unchanged: the run counted


def test_params_validation():
    with pytest.raises(ValidationError):
        _gate(probability=0.9, n_sigma=3.0)
    with pytest.raises(ValidationError):
        _gate(probability=1.5)
    with pytest.raises(ValidationError):
        _gate(n_sigma=-1.0)
    with pytest.raises(ValidationError):
        _gate(sigma=3.0)                       # unknown key: extra=forbid


@testing.parametrize_registered("filter")
def test_rejected_update_leaves_belief_untouched(name):
    """An outlier range is rejected by every filter: same belief object, NIS reported, counted."""
    flt = testing.build("filter", name)
    proc = testing.ConstantVelocity()
    meas = testing.RangeMeasurement(testing.RangeMeasurement.Params(beacons=[[0.0, 0.0], [10.0, 0.0]]))
    R = np.eye(2) * 0.01
    b = flt.predict(flt.initial_belief(0.0, [3.0, 4.0, 0.5, 0.0], np.eye(4) * 0.1), proc, None, 0.1)
    x_before, cov_before = b.x.copy(), b.cov.copy()
    gate = GateRun(_gate(n_sigma=3.0))
    z_good = meas.h(b.x)
    res = flt.update(b, meas, z_good + 0.01, R, gate=gate)
    assert res.accepted and res.belief is not b
    res = flt.update(b, meas, z_good + np.array([5.0, 0.0]), R, gate=gate)   # an echo, 5 m long
    assert res.accepted is False and res.belief is b
    assert np.array_equal(b.x, x_before) and np.array_equal(b.cov, cov_before)
    assert res.nis > gate.gate.threshold(2) == gate.last.threshold
    np.testing.assert_allclose(res.innovation, [5.0, 0.0], atol=0.2)
    assert gate.counters == {"rejected": 1, "checked": 2}   # counted in the run's GateRun; the filter keeps none


@pytest.mark.parametrize("name,params", [("chi2", {}), ("chi2", {"n_sigma": 3.0}), ("reopening", {}),
                                         ("reopening", {"window": 5, "start_open": True})])
def test_built_in_gates_pass_the_gate_contract(name, params):
    counts = testing.check_gate(testing.registry_class("gate", name), params)
    assert counts["checked"] == 400 and 0 < counts["rejected"] < 400


def test_the_gate_contract_catches_a_gate_that_counts_inside_itself():
    from fusion.api import Gate

    class Counting(Gate):
        """Counts its calls on itself (what a gate must not do)."""

        name = "counting"

        def check(self, nis, dim, state=None):
            self.calls = getattr(self, "calls", 0) + 1
            return GateDecision(bool(nis <= 9.0), 9.0), None

    with pytest.raises(AssertionError, match="immutable"):
        testing.check_gate(Counting)

    class NanPasses(Gate):
        """Accepts everything, NaN too."""

        name = "nan_passes"

        def check(self, nis, dim, state=None):
            return GateDecision(True, 9.0), None

    with pytest.raises(AssertionError, match="NaN"):
        testing.check_gate(NanPasses)


def test_the_gate_contract_catches_a_gate_that_changes_its_state_in_place():
    """A replay rewinds to states it kept: a gate that appends to the list it was given (instead of
    returning a new state) would rewrite history, and the kit says so."""
    from fusion.api import Gate

    class InPlace(Gate):
        """Remembers the recent NIS by appending to its state (what a gate must not do)."""

        name = "in_place"

        def initial_state(self) -> list:
            return []

        def check(self, nis, dim, state):
            state.append(nis)
            return GateDecision(bool(nis <= 9.0), 9.0), state

    with pytest.raises(AssertionError, match="changed the state"):
        testing.check_gate(InPlace)


@pytest.mark.parametrize("name,params", [("chi2", {"probability": 1e-200}), ("chi2", {"n_sigma": 1e155}),
                                         ("reopening", {"n_sigma": 1e155}), ("reopening", {"trigger_sigma": 1e200})])
def test_gate_parameters_out_of_a_meaningful_range_are_config_errors(name, params):
    """Values that pass a plain 'positive' check but cannot be computed (a chi-square quantile at 1e-200, an
    n-sigma whose square overflows) are refused when the config is read, not in the middle of a run."""
    from pydantic import ValidationError

    cls = testing.registry_class("gate", name)
    with pytest.raises(ValidationError):
        cls.Params(**params)


@pytest.mark.parametrize("dim", [2, 3, 6])
@pytest.mark.parametrize("n", [8.5, 9.0, 20.0, 38.0, 1000.0])
def test_n_sigma_gate_stays_closed_far_out(n, dim):
    """An n-sigma gate on a vector: ppf(cdf(n^2, 1)) rounds cdf to 1 from ~8.5 sigma (threshold inf, an open
    gate) and the tail probability underflows beyond ~37; the threshold is finite, of the 1-D tail's
    probability (checked by its own inverse, the tail of dim dof at it), and an absurd NIS is refused."""
    from fusion.chisquare import chi2 as c2

    g = _gate(n_sigma=n)
    thr = g.threshold(dim)
    assert math.isfinite(thr) and thr > n * n
    assert c2.logsf(thr, dim) == pytest.approx(c2.logsf(n * n, 1), rel=1e-12)
    assert g.accept(0.999 * thr, dim) and not g.accept(1.001 * thr, dim)
    assert not g.accept(1e12 if n < 100 else 1e13, dim)
