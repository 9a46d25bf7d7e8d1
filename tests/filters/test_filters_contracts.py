"""fusion.testing: the model contracts pass on good models and fail on broken ones; every registered
process model (and measurement model, on a registered process's layout) that builds with default
params is held to them."""
from __future__ import annotations

import numpy as np
import pytest

import pydantic

from fusion import testing
from fusion.api import Block, Message, StateLayout


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


# --------------------------------------------------------------------------- the built-ins, by the kit
# Every built-in model held to the same contract a third party's is (fusion.testing.check_*): built as a
# config builds it, a build error fails the test. Each needs the layout, params and (for models bound per
# message) a message a config would give it; a registered model without a case here fails
# test_every_builtin_has_a_contract_case, so none is skipped silently.
BEACONS = {"B1": [0.0, 0.0, 0.0], "B2": [20.0, 0.0, 1.0], "B3": [20.0, 15.0, 2.0], "B4": [0.0, 15.0, 0.5]}
INS = StateLayout.parse("p:3 v:3 q:4:quaternion ba:3 bw:3")
PV3 = StateLayout.parse("p:3 v:3")
CLOCK = StateLayout([Block("p", 3), Block("T", 1), Block("t", 1)])
CLOCK_Q = StateLayout([Block("p", 3), Block("T", 1), Block("t", 1), Block("q", 4, "quaternion")])
AHRS = StateLayout.parse("q:4:quaternion bw:3")
MAG = {"field_ned": [20.0, 1.0, 45.0]}
OMNI = StateLayout([Block("p", 3), Block("roll", 1, "angle"), Block("pitch", 1, "angle"), Block("yaw", 1, "angle"),
                    Block("vb", 3), Block("w", 3), Block("ab", 3)])
_C6 = tuple(0.01 if i == j else 0.0 for i in range(6) for j in range(i, 6))      # 6 x 6 upper triangle
_C3 = (0.01, 0.0, 0.0, 0.01, 0.0, 0.01)
_ODOM = (1.0, 2.0, 0.0, 0.98, 0.0, 0.0, 0.2, *_C6, 1.0, 0.1, 0.0, 0.0, 0.0, 0.2, *_C6)   # fusion import's Odometry

MEASUREMENT_CASES = [
    ("range", {}, PV3, Message(1.0, "uwb", ("B1", 5.0, "B3", 9.0))),
    ("range", {}, INS, Message(1.0, "uwb", ("B2", 5.0))),
    ("position", {}, PV3, None),
    ("position", {"lever_arm": (0.3, -0.1, 0.2)}, INS, None),
    ("position", {}, INS, Message(1.0, "abps", (1.0, 2.0, 3.0, 0.01, 0.0, 0.0, 0.01, 0.0, 0.02))),
    ("gps", {}, INS, None),
    ("magnetometer", MAG, INS, None),
    ("quat_norm", {}, INS, None),
    ("attitude", {}, INS, Message(1.0, "att", (0.9, 0.1, -0.3, 0.2))),
    ("arrival_time", {}, CLOCK, Message(1.0, "us", ("B2", 1.05))),
    # its default drops dh/dp from the Jacobian on purpose (position_from_direction: false): the full one here
    ("direction", {"position_from_direction": True, "receivers": "truncated_icosahedron"}, CLOCK_Q,
     Message(1.0, "us", ("B3", 1.05, 3))),
    ("pose", {"select": ["x", "y", "yaw", "vx", "vyaw"]}, OMNI, Message(1.0, "odom", _ODOM)),
    ("twist", {"select": ["vx", "vy", "vyaw"]}, OMNI, Message(1.0, "tw", _ODOM[28:])),
    ("imu", {"select": ["roll", "yaw", "vyaw", "ax"]}, OMNI,
     Message(1.0, "imu", (0.98, 0.1, 0.0, 0.2, 0.0, 0.0, 0.1, 0.2, 0.0, -9.8, *_C3, *_C3, *_C3))),
    ("gravity", {}, INS, Message(1.0, "acc", (0.3, -0.2, -9.7))),
    ("gravity", {}, AHRS, Message(1.0, "acc", (0.3, -0.2, -9.7, 0.01, 0.0, 0.02))),
    ("magnetometer_checked", MAG, AHRS, Message(1.0, "mag", (20.0, 1.0, 45.0))),
]
PROCESS_CASES = [("pv", {}), ("pv", {"dims": 3}), ("ins", {}), ("ins", {"states": 22}), ("firing_clock", {}),
                 ("firing_clock", {"attitude_sd_deg": 1.0}), ("static_orientation", {}), ("omni", {}),
                 ("omni", {"two_d_mode": True}), ("gyro_attitude", {})]


def test_every_builtin_has_a_contract_case():
    assert {n for n, *_ in MEASUREMENT_CASES} == set(testing.registered("measurement"))
    assert {n for n, _ in PROCESS_CASES} == set(testing.registered("process"))


@pytest.mark.parametrize("name,params,layout,message", MEASUREMENT_CASES,
                         ids=[f"{c[0]}-{i}" for i, c in enumerate(MEASUREMENT_CASES)])
def test_builtin_measurement_models_pass_the_kit(name, params, layout, message):
    cls = testing.registry_class("measurement", name)
    report = testing.check_measurement(cls, params, layout, beacons=BEACONS, message=message)
    assert report["jacobian"] < 1e-6


@pytest.mark.parametrize("name,params", PROCESS_CASES, ids=[f"{n}-{i}" for i, (n, _) in enumerate(PROCESS_CASES)])
def test_builtin_process_models_pass_the_kit(name, params):
    testing.check_process(testing.registry_class("process", name), params)


@testing.parametrize_registered("filter")
def test_builtin_filters_pass_the_kit(name):
    assert testing.check_filter(testing.registry_class("filter", name)) < 1e-9


def test_the_kit_fails_loudly_on_a_build_error_and_on_bad_declarations():
    from fusion.api import ConfigError

    with pytest.raises(ConfigError, match="position block"):      # range on a state without p: not skipped
        testing.check_measurement(testing.registry_class("measurement", "range"), {}, StateLayout.parse("q:4"))

    class Unnamed(testing.PositionMeasurement):
        name = ""

    with pytest.raises(AssertionError, match="no registry name"):
        testing.check_component(Unnamed)

    class Loose(testing.PositionMeasurement):
        """Position, with a Params model that lets unknown keys through."""

        class Params(pydantic.BaseModel):
            dim: int = 2

    with pytest.raises(AssertionError, match="fusion.api.Params"):
        testing.check_component(Loose)

    class Typo(testing.ConstantVelocity):
        """Constant velocity with a misspelt batched-input fast path."""

        def f_input(self, x, us, dts):   # one edit away from the capability f_inputs
            return x

    with pytest.raises(AssertionError, match="f_input looks like capability member 'f_inputs'"):
        testing.check_process(Typo)

    class FalselyLinear(testing.RangeMeasurement):
        """Ranges that claim to be linear."""

        linear = True

    with pytest.raises(AssertionError, match="declares linear = True"):
        testing.check_measurement(FalselyLinear, {"beacons": [[0.0, 0.0], [5.0, 1.0]]}, StateLayout.parse("p:2 v:2"))


class NumericallyBroken(testing.RangeMeasurement):
    """Ranges whose h is not the function its batch gives: no analytic Jacobian, and h jumps."""

    def h(self, x):
        r = super().h(x)
        return r + 1e-3 * np.sign(np.sin(1e4 * np.asarray(x)[..., :1]))

    def jacobian(self, x):
        return None


def test_the_numerical_jacobian_is_checked_when_there_is_no_analytic_one():
    lay = StateLayout.parse("p:2 v:2")
    report = testing.check_measurement(testing.RangeMeasurement, {"beacons": [[0.0, 0.0], [5.0, 1.0]],
                                                                  "analytic_jacobian": False}, lay)
    assert report["jacobian"] < 1e-6
    with pytest.raises(AssertionError, match="numerical Jacobian \\(no analytic one\\) differs"):
        testing.check_measurement(NumericallyBroken, {"beacons": [[0.0, 0.0], [5.0, 1.0]]}, lay)
