"""fusion.run.measure.measure: one update as a function of its arguments. Checked against the Kalman update in
closed form on a linear model (1-D position and bias, a direct position fix), and for what it must not do:
change the belief it is given, or anything of the loop's."""
import sys
from pathlib import Path

import numpy as np
import pytest

from fusion.api import Belief, Gate, GateDecision, MeasurementModel, Observation
from fusion.run.measure import measure
from fusion.run.plan import plan_sensor

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))
from test_scheduler_inputs import system as odo_system  # noqa: E402


class Direct(MeasurementModel):
    """z = p (the first state element), an analytic Jacobian."""

    name = "direct_test"
    dim = 1

    def __init__(self, h=None):
        self._h = h

    def h(self, x):
        return self._h(x) if self._h is not None else x[..., :1]

    def jacobian(self, x):
        return np.array([[1.0, 0.0]])


class Initial(Direct):
    initialises = True


class Never(Gate):
    name = "never_test"

    def check(self, nis, dim, state):
        return GateDecision(False, 0.0), state


def _setup(gate=None):
    system = odo_system()
    sensor = system.sensors["fix"]
    sensor.gate = gate
    belief = Belief(1.0, np.array([0.5, 0.1]), P=np.array([[0.4, 0.05], [0.05, 0.2]]))
    return system.filter, belief, plan_sensor(sensor, 0.0), system.layout


def test_the_update_is_the_kalman_update_in_closed_form():
    filt, belief, plan, layout = _setup()
    R = np.array([[0.01]])
    out = measure(filt, belief, Observation(1.0, np.array([0.8]), Direct(), R), R, plan, layout)
    H = np.array([[1.0, 0.0]])
    S = H @ belief.P @ H.T + R
    K = belief.P @ H.T / S
    y = 0.8 - 0.5
    # rounding of a 2x2 update of values O(1): 1e-12 is some thousand float64 epsilons
    np.testing.assert_allclose(out.belief.x, belief.x + (K * y).ravel(), rtol=0, atol=1e-12)
    np.testing.assert_allclose(out.belief.cov, (np.eye(2) - K @ H) @ belief.P, rtol=0, atol=1e-12)
    assert out.result.nis == pytest.approx(y * y / S[0, 0], rel=1e-12)
    assert out.verdict == "used" and out.counts == {"used": 1} and len(out.results) == 1 and out.failure is None


def test_the_step_changes_neither_its_belief_nor_the_sensor():
    filt, belief, plan, layout = _setup()
    x, P, counters = belief.x.copy(), belief.P.copy(), dict(plan.runtime.counters)
    R = np.array([[0.01]])
    obs = Observation(1.0, np.array([0.8]), Direct(), R)
    a = measure(filt, belief, obs, R, plan, layout)
    b = measure(filt, belief, obs, R, plan, layout)
    np.testing.assert_array_equal(belief.x, x)
    np.testing.assert_array_equal(belief.P, P)
    assert plan.runtime.counters == counters        # the loop counts the outcome's counts, not the step
    np.testing.assert_array_equal(a.belief.x, b.belief.x)


def test_a_rejected_update_keeps_the_belief_given():
    filt, belief, plan, layout = _setup(gate=Never())
    R = np.array([[0.01]])
    out = measure(filt, belief, Observation(1.0, np.array([0.8]), Direct(), R), R, plan, layout)
    assert out.verdict == "rejected" and out.counts == {"rejected": 1} and out.belief is belief
    assert plan.gate.counters["rejected"] == 1       # the gate's run state is the run's, counted there


def test_a_model_that_initialises_the_state_is_not_gated():
    filt, belief, plan, layout = _setup(gate=Never())
    R = np.array([[0.01]])
    out = measure(filt, belief, Observation(1.0, np.array([0.8]), Initial(), R), R, plan, layout)
    assert out.verdict == "used" and plan.gate.counters["checked"] == 0


def test_a_model_that_raises_is_the_outcome_s_failure_not_an_exception():
    def boom(x):
        raise ZeroDivisionError("no")

    filt, belief, plan, layout = _setup()
    R = np.array([[0.01]])
    out = measure(filt, belief, Observation(1.0, np.array([0.8]), Direct(boom), R), R, plan, layout)
    assert isinstance(out.failure, ZeroDivisionError) and out.belief is belief and out.counts == {}
    assert out.results == () and out.result is None


def test_a_model_whose_prediction_is_not_finite_fails_the_step_and_keeps_the_belief():
    """The filter finds h NaN at a finite mean (a ModelFault): the outcome's failure, the belief given kept."""
    from fusion.errors import ModelFault

    filt, belief, plan, layout = _setup()
    R = np.array([[0.01]])
    out = measure(filt, belief, Observation(1.0, np.array([0.8]), Direct(lambda x: x[..., :1] * np.nan), R), R,
                  plan, layout)
    assert isinstance(out.failure, ModelFault) and out.belief is belief and out.counts == {}
