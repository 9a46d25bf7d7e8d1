"""Interface details every filter honours: registry and Params, normalize on predicted and updated
means, dt = 0, augmented noise in the UKF."""
from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from fusion import testing
from fusion.api import Belief, BuildContext, Filter, MeasurementModel, ProcessModel, StateLayout
from fusion.registry import default_registry


@testing.parametrize_registered("filter")
def test_registered_filter_declares_itself(name):
    cls = default_registry().get("filter", name)
    assert issubclass(cls, Filter) and cls.kind == "filter" and cls.name == name
    assert cls.__doc__ and len(cls.__doc__) > 200            # the equations
    with pytest.raises(ValidationError):
        cls.Params(not_a_parameter=1)


def test_params():
    assert testing.build("filter", "iekf", {"max_iterations": 3}).params.max_iterations == 3
    with pytest.raises(ValidationError):
        testing.build("filter", "iekf", {"max_iterations": 0})
    with pytest.raises(ValidationError):
        testing.build("filter", "ukf", {"alpha": 0.0})
    with pytest.raises(ValidationError):
        testing.build("filter", "srukf", {"zeroth_point": "median"})
    with pytest.raises(ValueError, match="kappa"):
        ukf = testing.build("filter", "ukf", {"kappa": -10.0, "linear_prediction": "never"})
        ukf.predict(ukf.initial_belief(0.0, np.zeros(4), np.eye(4)), testing.ConstantVelocity(), None, 0.1)


def test_kf_refuses_a_nonlinear_process():
    from fusion.api import ConfigError

    class Bent(testing.ConstantVelocity):
        linear = False

    kf = testing.build("filter", "kf")
    with pytest.raises(ConfigError, match="linear"):
        kf.predict(kf.initial_belief(0.0, np.zeros(4), np.eye(4)), Bent(), None, 0.1)


class Spin(ProcessModel):
    """A unit quaternion q:4 rotating at a constant rate about z; f lets the norm drift (by 1 + 1e-3)."""

    name = "test_spin"
    layout = StateLayout.parse("q:4")
    linear = True   # q (x) dq times 1.001 is linear in q: the kf takes it too

    def f(self, x, u, dt):
        x = np.asarray(x, dtype=float)
        h = 0.5 * 0.3 * dt
        w, a, b, c = np.moveaxis(x, -1, 0)
        ch, sh = np.cos(h), np.sin(h)   # q (x) [cos h, 0, 0, sin h]
        return 1.001 * np.stack([w * ch - c * sh, a * ch + b * sh, b * ch - a * sh, c * ch + w * sh], -1)

    def Q(self, x, u, dt):
        return np.eye(4) * 1e-6 * dt

    def normalize(self, x):
        return x / np.linalg.norm(x[..., :4], axis=-1, keepdims=True)


class QuatDirect(MeasurementModel):
    name = "test_quat_direct"
    dim = 4
    linear = True

    def h(self, x):
        return np.asarray(x, dtype=float)[..., :4].copy()


@testing.parametrize_registered("filter")
def test_normalize_applied_to_predicted_and_updated_mean(name):
    # wired as a config wires it: the filter knows the state layout (its unit quaternion block q)
    flt = testing.build("filter", name, context=BuildContext(layout=Spin.layout))
    b = flt.initial_belief(0.0, [1.0, 0.0, 0.0, 0.0], np.eye(4) * 1e-3)
    # an update before any predict is normalised too (no process model remembered from a predict)
    b0 = flt.update(b, QuatDirect(), np.array([1.0, 0.2, 0.0, 0.0]), np.eye(4) * 1e-2).belief
    assert abs(np.linalg.norm(b0.x) - 1.0) < 1e-12 and b0.x[1] > 0.01   # moved, and back on the unit sphere
    for k in range(5):
        b = flt.predict(b, Spin(), None, 0.1)
        assert abs(np.linalg.norm(b.x) - 1.0) < 1e-12
        z = np.array([1.0, 0.02, -0.01, 0.1 * k])
        b = flt.update(b, QuatDirect(), z, np.eye(4) * 1e-2).belief
        assert abs(np.linalg.norm(b.x) - 1.0) < 1e-12


@testing.parametrize_registered("filter")
def test_zero_dt_predict_is_identity(name):
    flt = testing.build("filter", name)
    b = flt.initial_belief(2.0, [1.0, 2.0, 0.5, 0.0], np.eye(4))
    out = flt.predict(b, testing.ConstantVelocity(), None, 0.0)
    assert out.t == 2.0 and np.array_equal(out.x, b.x) and np.array_equal(out.cov, b.cov)


def test_belief_given_as_P_to_srukf_and_as_S_to_ukf():
    """Filters accept the other representation (a config switching filters mid-run)."""
    proc = testing.ConstantVelocity()
    P0 = np.diag([1.0, 2.0, 0.5, 0.3])
    x0 = np.array([1.0, 2.0, 0.5, 0.0])
    sr, ukf = testing.build("filter", "srukf"), testing.build("filter", "ukf")
    a = sr.predict(Belief(0.0, x0, P=P0), proc, None, 0.1)
    b = ukf.predict(Belief(0.0, x0, S=np.linalg.cholesky(P0)), proc, None, 0.1)
    np.testing.assert_allclose(a.cov, b.cov, atol=1e-14)


class MultiplicativeNoise(ProcessModel):
    """x' = x (1 + w): noise that enters non-linearly (1-D), for the augmented UKF."""

    name = "test_mult"
    layout = StateLayout.parse("x:1")

    def f(self, x, u, dt):
        return np.asarray(x, dtype=float).copy()

    def f_with_noise(self, x, w, u, dt):
        return x * (1.0 + w)

    def Q(self, x, u, dt):
        return np.array([[0.04]])


def test_augmented_ukf_samples_nonadditive_noise():
    mu, P = 3.0, 0.5
    b = Belief(0.0, np.array([mu]), P=np.array([[P]]))
    aug = testing.build("filter", "ukf", {"augmented": True})
    plain = testing.build("filter", "ukf")
    pa = aug.predict(b, MultiplicativeNoise(), None, 1.0)
    pp = plain.predict(b, MultiplicativeNoise(), None, 1.0)
    # the unscented transform of x (1 + w): mean mu, variance P + mu^2 Q (its axis-aligned points miss
    # the P Q cross term); the additive default would give P + Q
    assert pa.x[0] == pytest.approx(mu)
    assert pa.P[0, 0] == pytest.approx(P + mu * mu * 0.04, rel=1e-12)
    assert pp.P[0, 0] == pytest.approx(P + 0.04, rel=1e-12)


def test_augmented_ukf_is_exact_on_linear_models():
    assert testing.check_filter_linear_exactness(testing.build("filter", "ukf", {"augmented": True})) < 1e-9


class Counting:
    """Wraps a model and records the shape of every f / h call."""

    def __init__(self, inner):
        self.inner, self.calls = inner, []

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def f(self, x, u, dt):
        self.calls.append(np.shape(x))
        return self.inner.f(x, u, dt)

    def h(self, x):
        self.calls.append(np.shape(x))
        return self.inner.h(x)


@pytest.mark.parametrize("name,params", [
    ("ukf", {"linear_prediction": "never"}), ("srukf", {"linear_prediction": "never"}),
    ("srukf", {"linear_prediction": "never", "zeroth_point": "cholupdate"}),
    ("ukf", {"linear_prediction": "never", "augmented": True}),
])
def test_sigma_point_filters_call_the_models_once_per_step(name, params):
    proc = Counting(testing.ConstantVelocity())
    meas = Counting(testing.RangeMeasurement(testing.RangeMeasurement.Params(beacons=[[0.0, 0.0], [9.0, 1.0]])))
    flt = testing.build("filter", name, params)
    b = flt.initial_belief(0.0, [3.0, 4.0, 0.5, 0.0], np.eye(4))
    for _ in range(3):
        b = flt.update(flt.predict(b, proc, None, 0.1), meas, meas.h(b.x) + 0.1, np.eye(2) * 0.01).belief
    k = 2 * (4 + 4) + 1 if params.get("augmented") else 9
    assert proc.calls == [(k, 4)] * 3
    k = 2 * (4 + 2) + 1 if params.get("augmented") else 9
    assert [c for c in meas.calls if c != (4,)] == [(k, 4)] * 3


def test_ekf_numerical_jacobians_are_one_call_each():
    proc = Counting(testing.ConstantVelocity(testing.ConstantVelocity.Params(analytic_jacobian=False)))
    meas = Counting(testing.RangeMeasurement(testing.RangeMeasurement.Params(
        beacons=[[0.0, 0.0], [9.0, 1.0]], analytic_jacobian=False)))
    ekf = testing.build("filter", "ekf")
    b = ekf.predict(ekf.initial_belief(0.0, [3.0, 4.0, 0.5, 0.0], np.eye(4)), proc, None, 0.1)
    assert sorted(proc.calls) == [(4,), (8, 4)]          # f(x) and one batch of 2n perturbed states
    ekf.update(b, meas, np.array([5.0, 6.5]), np.eye(2) * 0.01)
    assert sorted(meas.calls) == [(4,), (8, 4)]
