"""The INS across an IMU gap that other sensors cut into several predictions (fusion.api.HoldsInput):
the held sample is integrated over ``hold_after`` since its own time only, and the hold noise of the gap
is the same however the gap is cut (ins_batch.add_hold_noise, issue: IMU-only dropouts)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError
from scipy import integrate

from fusion import quaternion as quat
from fusion.api import BuildContext, HoldsInput, has
from fusion.config import build_component
from fusion.registry import default_registry
from fusion_plugins.process.ins import coast
from fusion_plugins.process.ins_batch import gm_rate_noise, integrated_gm_variance
from fusion_plugins.process.ins_params import InsParams


def make(**kw):
    return build_component(default_registry(), "process", {"type": "ins", **kw}, BuildContext())


HOLD = dict(hold_after=0.03, hold_accel_sd=1.0, hold_yaw_rate_sd=0.3, hold_tilt_rate_sd=0.05, hold_motion_tau=2.0)


def state(n, rng):
    x = np.zeros(n)
    x[0:6] = rng.normal(size=6)
    x[6:10] = quat.normalize(rng.normal(size=4))
    if n >= 16:
        x[10:16] = rng.normal(scale=0.01, size=6)
    if n == 22:
        x[16:22] = 1.0 + rng.normal(scale=0.01, size=6)
    return x


@pytest.mark.parametrize("sd,tau,e", [(0.3, 2.0, 0.005), (0.3, 2.0, 1.0), (1.0, 0.5, 7.0), (0.02, 10.0, 0.3)])
def test_integrated_gauss_markov_variance_against_the_double_integral(sd, tau, e):
    # Var(int_0^e b) = int_0^e int_0^e sd^2 exp(-|s - t| / tau) ds dt: twice the triangle s < t (a smooth
    # integrand there), by scipy's quadrature
    ref, _ = integrate.dblquad(lambda s, t: 2.0 * sd * sd * math.exp(-(t - s) / tau), 0.0, e, 0.0, lambda t: t,
                               epsabs=1e-14, epsrel=1e-11)
    # dblquad was asked for 1e-11 relative and estimates its error at <= 6e-12 of the value on these cases:
    # 1e-7 is 1e4 times that, and a wrong closed form (a lost term of order e / tau) is off by far more
    assert integrated_gm_variance(sd, tau, e) == pytest.approx(ref, rel=1e-7)


def test_integrated_gauss_markov_variance_is_continuous_where_the_series_takes_over():
    tau = 2.0
    below, above = integrated_gm_variance(1.0, tau, tau * (1e-3 - 1e-12)), integrated_gm_variance(1.0, tau, tau * 1e-3)
    assert below == pytest.approx(above, rel=1e-8)
    assert integrated_gm_variance(1.0, tau, 1e-9) == pytest.approx(1e-18, rel=1e-6)   # sd^2 e^2 for e << tau


@pytest.mark.parametrize("states", [16, 22])
def test_a_sample_held_past_hold_after_is_not_integrated_again(states):
    m = make(states=states, **HOLD)
    assert has(m, HoldsInput) and m.hold_after == 0.03
    rng = np.random.default_rng(states)
    x = state(m.layout.n, rng)
    u = np.r_[0.3, -0.2, -9.7, 0.2, -0.1, 0.4]                      # a turn: integrating it moves q
    late = m.held(0.5)
    np.testing.assert_array_equal(late.f(x, u, 0.2), coast(x, 0.2))   # past hold_after: a pure coast
    # within what is left of hold_after: an ordinary step, to the last bit
    np.testing.assert_array_equal(m.held(0.01).f(x, u, 0.015), m.f(x, u, 0.015))
    # the gap cut at 0.2 s: the same mean as in one prediction (the old rule integrated u again per piece)
    two = m.held(0.2).f(m.f(x, u, 0.2), u, 0.3)
    np.testing.assert_allclose(two, m.f(x, u, 0.5), atol=1e-12)
    assert not np.allclose(m.f(m.f(x, u, 0.2), u, 0.3)[6:10], two[6:10], atol=1e-4)
    assert m.held(0.0) is m and make(states=states).held(1.0).hold_after is None


@pytest.mark.parametrize("states", [16, 22])
def test_the_noise_of_a_gap_does_not_depend_on_how_it_is_cut(states):
    # EKF propagation P <- F P F^T + Q through one 3 s prediction and through the same gap cut by
    # measurements every 1/6 s (a magnetometer): the velocity and attitude covariances agree (the coast's
    # F composes exactly and the hold noise adds what accrued over each piece).
    # (no rotation in the sample nor a gyro bias: the hold_after it is integrated over then leaves q, where
    # the hold noise is expressed, the same in both; with a rotation they differ by ~2e-4 of the block)
    m = make(states=states, **HOLD, hold_max_attitude_sd=3.0)   # the one-step bound not reached (see below)
    rng = np.random.default_rng(7)
    x = state(m.layout.n, rng)
    x[10:16] = 0.0
    u = np.r_[0.3, -0.2, -9.7, 0.0, 0.0, 0.0]
    P0 = np.eye(m.layout.n) * 1e-4
    T = 3.0

    def step(model, x, P, dt):
        F = model.jacobian(x, u, dt)
        return model.f(x, u, dt), F @ P @ F.T + model.Q(x, u, dt)

    x1, P1 = step(m, x, P0, T)
    cuts = np.r_[0.0, np.arange(1, 19) / 6.0, T]
    xk, Pk = step(m, x, P0, cuts[1])
    for a, b in zip(cuts[1:-1], cuts[2:]):
        xk, Pk = step(m.held(a), xk, Pk, b - a)
    np.testing.assert_allclose(xk, x1, atol=1e-12)
    np.testing.assert_allclose(Pk[3:6, 3:6], P1[3:6, 3:6], rtol=1e-9)
    np.testing.assert_allclose(Pk[6:10, 6:10], P1[6:10, 6:10], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(Pk[0:6, 0:6], P1[0:6, 0:6], rtol=1e-9)
    # and the velocity sd is the acceleration's integral over the whole gap (3.6 m/s after 3 s at 1 m/s^2)
    assert Pk[3, 3] == pytest.approx(integrated_gm_variance(1.0, 2.0, T - 0.03) + P0[3, 3], rel=1e-3)
    # hold_max_attitude_sd bounds what ONE prediction adds (a pause of every stream): 0.5 rad of heading in
    # the single 3 s step (its 0.72 rad unbounded), while the cut gap, held by its measurements, may open more
    bounded = make(states=states, **HOLD)
    q0, q1, q2, q3 = x[6:10]
    Xi = np.array([[-q1, -q2, -q3], [q0, q3, -q2], [-q3, q0, q1], [q2, -q1, q0]])
    added = bounded.Q(x, u, T) - make(states=states, hold_after=None).Q(x, u, T)
    assert np.sqrt(4.0 * Xi[:, 2] @ added[6:10, 6:10] @ Xi[:, 2]) == pytest.approx(0.5, rel=1e-9)


@pytest.mark.parametrize("e0,e1", [(0.0, 0.004), (0.0, 3.0), (0.7, 1.9), (4.0, 12.0)])
def test_the_position_noise_is_that_of_the_white_noise_of_the_velocity_variance_rate(e0, e1):
    sd, tau = 0.8, 2.0
    q = lambda t: 2 * sd * sd * tau * (1 - math.exp(-t / tau))          # dG/dt
    ref = [integrate.quad(lambda t: q(t) * (e1 - t) ** k, e0, e1, epsabs=1e-15, epsrel=1e-12)[0] for k in range(3)]
    vv, pv, pp = gm_rate_noise(sd, tau, e0, e1)
    # quad was asked for 1e-12 relative (1e-15 absolute) on smooth integrands; the closed forms round at ~1e-15 m^2:
    # rtol 1e-8 is 1e4 times the quadrature's tolerance (measured under 3 % of it)
    np.testing.assert_allclose([vv, pv, pp], ref, rtol=1e-8, atol=1e-13)
    assert np.linalg.eigvalsh(np.array([[pp, pv], [pv, vv]])).min() >= -1e-15


def test_heading_opens_and_tilt_stays_tight_during_a_gap():
    m = make(states=16, **HOLD)
    x = state(16, np.random.default_rng(3))
    q0, q1, q2, q3 = x[6:10]
    Xi = np.array([[-q1, -q2, -q3], [q0, q3, -q2], [-q3, q0, q1], [q2, -q1, q0]])
    Q = m.held(1.0).Q(x, np.r_[0, 0, -9.8, 0, 0, 0], 0.5)
    sd = np.sqrt(np.diag(4.0 * Xi.T @ Q[6:10, 6:10] @ Xi))             # N, E, D attitude error sds
    want = np.sqrt([integrated_gm_variance(s, 2.0, 1.47) - integrated_gm_variance(s, 2.0, 0.97)
                    for s in (0.05, 0.05, 0.3)])
    np.testing.assert_allclose(sd, want, rtol=0.02, atol=3e-4)          # (+ the gyro's white noise)
    assert sd[2] > 5 * sd[0]


def test_the_old_hold_parameters_are_refused_with_their_replacements():
    with pytest.raises(ValidationError, match="hold_accel_rw was replaced by hold_accel_sd"):
        InsParams(hold_after=0.03, hold_accel_rw=0.7)
    with pytest.raises(ValidationError, match="hold_yaw_rate_sd and hold_tilt_rate_sd"):
        InsParams(hold_rate_rw=1.0)
