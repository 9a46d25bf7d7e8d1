"""fusion.testing: the model contracts pass on good models and fail on broken ones; every registered
process model (and measurement model, on a registered process's layout) that builds with default
params is held to them."""
from __future__ import annotations

import numpy as np
import pytest

from fusion import testing
from fusion.api import BuildContext


def test_reference_models_pass():
    cv = testing.ConstantVelocity(testing.ConstantVelocity.Params(dims=3))
    X = testing.random_states(cv.layout, 7, seed=1)
    testing.check_process_vectorised(cv, X, None, 0.1)
    assert testing.check_process_jacobian(cv, X[0], None, 0.1) < 1e-8
    rng = testing.RangeMeasurement(testing.RangeMeasurement.Params(
        beacons=[[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0]]))
    X = testing.random_states(testing.ConstantVelocity().layout, 7, seed=2, scale=5.0)
    testing.check_measurement_vectorised(rng, X)
    assert testing.check_measurement_jacobian(rng, X[0]) < 1e-6
    pos = testing.PositionMeasurement()
    testing.check_measurement_vectorised(pos, X)
    testing.check_measurement_jacobian(pos, X[0])


class NotVectorised(testing.ConstantVelocity):
    def f(self, x, u, dt):
        x = np.asarray(x, dtype=float)
        return x + dt * np.concatenate([x[2:4], [0.0, 0.0]]) if x.ndim == 1 else x  # batch path wrong


class WrongJacobian(testing.ConstantVelocity):
    def jacobian(self, x, u, dt):
        return np.eye(4)


class WrongRangeJacobian(testing.RangeMeasurement):
    def jacobian(self, x):
        return -super().jacobian(x)


def test_contracts_catch_broken_models():
    X = testing.random_states(testing.ConstantVelocity().layout, 5)
    with pytest.raises(AssertionError, match="row by row"):
        testing.check_process_vectorised(NotVectorised(), X, None, 0.1)
    with pytest.raises(AssertionError, match="finite differences"):
        testing.check_process_jacobian(WrongJacobian(), X[0], None, 0.1)
    bad = WrongRangeJacobian(testing.RangeMeasurement.Params(beacons=[[0.0, 0.0], [5.0, 1.0]]))
    with pytest.raises(AssertionError, match="finite differences"):
        testing.check_measurement_jacobian(bad, X[0])


def test_filter_contract_catches_a_wrong_filter():
    class Overconfident(type(testing.build("filter", "ekf"))):
        def update(self, belief, model, z, R, gate=None):
            return super().update(belief, model, z, np.asarray(R) * 0.5, gate)

    with pytest.raises(AssertionError, match="textbook KF"):
        testing.check_filter_linear_exactness(Overconfident())


def _buildable(kind, context=None):
    out = []
    for name in testing.registered(kind):
        try:
            out.append(testing.build(kind, name, context=context))
        except Exception:  # needs params or a context we cannot guess: not testable generically
            pass
    return out


@pytest.mark.parametrize("process", _buildable("process"), ids=lambda p: p.name)
def test_registered_process_models(process):
    X = testing.random_states(process.layout, 9, seed=4)
    u = np.zeros(process.input_dim) if process.input_dim else None
    testing.check_process_vectorised(process, X, u, 0.01)
    testing.check_process_jacobian(process, X[0], u, 0.01)


def _measurement_cases():
    cases = []
    beacons = {"B1": np.array([0.0, 0.0, 0.0]), "B2": np.array([20.0, 0.0, 1.0]),
               "B3": np.array([20.0, 15.0, 2.0]), "B4": np.array([0.0, 15.0, 0.5])}
    for proc in _buildable("process"):
        ctx = BuildContext(layout=proc.layout, beacons=beacons)
        for meas in _buildable("measurement", ctx):
            cases.append(pytest.param(proc, meas, id=f"{meas.name}-on-{proc.name}"))
    return cases


@pytest.mark.parametrize("process,meas", _measurement_cases())
def test_registered_measurement_models(process, meas):
    X = testing.random_states(process.layout, 9, seed=5, scale=3.0)
    try:
        meas.h(X[0])
    except Exception as exc:  # e.g. range binds to the beacons a message names: nothing to evaluate yet
        pytest.skip(f"{meas.name}: h is not usable before a message binds it ({type(exc).__name__})")
    testing.check_measurement_vectorised(meas, X)
    testing.check_measurement_jacobian(meas, X[0])
