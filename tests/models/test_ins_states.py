"""Process ``ins`` with the paper-002 state sets (10 and 22 states, eqs. 8, 11-13)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion import quaternion as quat
from fusion.api import BuildContext
from fusion.config import build_component
from fusion.registry import default_registry
from fusion_plugins.filters.jacobian import numerical_jacobian
from fusion_plugins.process.ins import Ins, InsParams
from fusion_plugins.process.ins_states import InsStates

G = 9.80665


def make(**kw):
    return build_component(default_registry(), "process", {"type": "ins", **kw}, BuildContext())


def random_state(rng, states):
    x = np.zeros(states)
    x[0:6] = rng.normal(0, 3, 6)
    x[6:10] = Rotation.random(random_state=rng).as_quat(scalar_first=True)
    if states >= 16:
        x[10:13] = rng.normal(0, 0.1, 3)
        x[13:16] = rng.normal(0, 0.01, 3)
    if states == 22:
        x[16:22] = 1.0 + rng.normal(0, 0.03, 6)
    return x


def imu(rng):
    return np.r_[rng.normal(0, 2, 3) + [0, 0, -G], rng.normal(0, 0.5, 3)]


def test_states_select_the_layout_and_16_is_the_paper_000_model():
    assert type(make()) is Ins and type(make(states=16)) is Ins
    m10, m22 = make(states=10), make(states=22)
    assert isinstance(m10, InsStates) and isinstance(m22, InsStates)
    assert [b.name for b in m10.layout.blocks] == ["p", "v", "q"]
    assert [b.name for b in m22.layout.blocks] == ["p", "v", "q", "ba", "bw", "sa", "sw"]
    assert m22.layout.n == 22 and m22.layout["sw"] == slice(19, 22)


def test_scale_rw_needs_22_states():
    from fusion.api import ConfigError
    with pytest.raises(ConfigError, match="states: 22"):
        make(states=16, accel_scale_rw=1e-4)


@pytest.mark.parametrize("integration", ["euler", "trapezoidal"])
def test_22_states_equal_16_fed_the_true_input(integration):
    """Eq. 11: with u~ = s u + b, the 22-state step equals the 16-state step fed the true u (zero bias)."""
    rng = np.random.default_rng(1)
    m16, m22 = make(integration=integration), make(states=22, integration=integration)
    for _ in range(20):
        x = random_state(rng, 22)
        u_true = imu(rng)
        u_meas = x[16:22] * u_true + x[10:16]
        y22 = m22.f(x, u_meas, 0.02)
        x16 = np.r_[x[:10], np.zeros(6)]
        y16 = m16.f(x16, u_true, 0.02)
        np.testing.assert_allclose(y22[:10], y16[:10], atol=1e-13)
        np.testing.assert_array_equal(y22[10:], x[10:])       # eqs. 12-13: random walks, mean kept


def test_22_states_with_unit_scale_equal_the_16_state_model():
    rng = np.random.default_rng(2)
    m16, m22 = make(), make(states=22)
    x = random_state(rng, 22)
    x[16:22] = 1.0
    u = imu(rng)
    np.testing.assert_allclose(m22.f(x, u, 0.02)[:16], m16.f(x[:16], u, 0.02), atol=1e-14)
    Q22, Q16 = m22.Q(x, u, 0.02), m16.Q(x[:16], u, 0.02)
    np.testing.assert_allclose(Q22[:16, :16], Q16, atol=1e-18)


@pytest.mark.parametrize("states", [10, 22])
@pytest.mark.parametrize("kw", [{}, {"integration": "trapezoidal"}, {"eta": 10.0}])
def test_analytic_jacobian_matches_numerical(states, kw):
    rng = np.random.default_rng(3)
    m = make(states=states, **kw)
    for _ in range(5):
        x = random_state(rng, states)
        u = imu(rng)
        F = m.jacobian(x, u, 0.02)
        Fn = numerical_jacobian(lambda X: m.f(X, u, 0.02), x)
        np.testing.assert_allclose(F, Fn, atol=2e-8)


@pytest.mark.parametrize("states", [10, 22])
def test_vectorised_and_run_of_samples_equal_one_by_one(states):
    rng = np.random.default_rng(4)
    m = make(states=states)
    X = np.array([random_state(rng, states) for _ in range(7)])
    us = np.array([imu(rng) for _ in range(9)])
    dts = rng.uniform(0.015, 0.025, 9)
    ref = X.copy()
    for u, dt in zip(us, dts):
        ref = np.array([m.f(x, u, dt) for x in ref])
    np.testing.assert_allclose(m.f_inputs(X, us, dts), ref, atol=1e-12)


def test_noise_blocks():
    m = make(states=22, accel_scale_rw=2e-4, gyro_scale_rw=3e-4)
    x = random_state(np.random.default_rng(5), 22)
    Q = m.Q(x, np.zeros(6), 0.02)
    assert Q.shape == (22, 22) and np.allclose(Q, Q.T)
    np.testing.assert_allclose(np.diag(Q)[16:], [4e-8 * 0.02] * 3 + [9e-8 * 0.02] * 3)
    assert np.linalg.eigvalsh(Q).min() > -1e-18
    Qi = m.Q_inputs(x, m.f(x, np.r_[0, 0, -G, 0, 0, 0], 0.1), np.array([[0, 0, -G, 0, 0, 0.0]]), np.array([0.1]))
    np.testing.assert_allclose(np.diag(Qi)[16:], [4e-8 * 0.1] * 3 + [9e-8 * 0.1] * 3)
    assert make(states=10).Q(x[:10], None, 0.02).shape == (10, 10)


def test_align_with_scale_and_bias_levels_exactly():
    """A static IMU reads u~ = s (.) (-C_n^b g_n) + b (eq. 11): levelling with the state's b and s recovers
    roll and pitch exactly; the gyro bias becomes the static rate."""
    m = make(states=22)
    rng = np.random.default_rng(6)
    q_true = quat.from_euler(0.1, -0.05, 0.7)
    x0 = np.r_[np.zeros(6), quat.from_euler(0, 0, 0.7), rng.normal(0, 0.1, 3), np.zeros(3), 1 + rng.normal(0, 0.03, 6)]
    f = quat.to_matrix(q_true).T @ np.array([0, 0, -G])
    bw = np.array([0.01, -0.02, 0.005])
    u = np.r_[x0[16:19] * f + x0[10:13], bw]
    x, P = m.align(x0, np.eye(22), u)
    assert quat.angle_between(x[6:10], q_true) < 1e-12
    np.testing.assert_allclose(x[13:16], bw)
    np.testing.assert_array_equal(P, np.eye(22))
    x10, _ = make(states=10).align(np.r_[np.zeros(6), 1, 0, 0, 0], np.eye(10), np.r_[f, bw])
    assert quat.angle_between(x10[6:10], quat.from_euler(0.1, -0.05, 0.0)) < 1e-12


@pytest.mark.parametrize("states", [10, 22])
def test_one_point_fast_path_equals_the_general_path(states):
    """The EKF's scalar fast path (f, F, Q for one state) gives the general path's numbers to rounding,
    and a step longer than hold_after goes the general way (hold noise)."""
    rng = np.random.default_rng(7)
    kw = {"accel_scale_rw": 1e-4, "gyro_scale_rw": 2e-4} if states == 22 else {}
    fast = make(states=states, quat_norm_variance=1e-12, hold_after=0.03, **kw)
    slow = make(states=states, quat_norm_variance=1e-12, hold_after=0.03, **kw)
    slow._fast = False
    assert fast._fast
    for dt in (0.02, 0.02, 0.01, 0.5):
        x = random_state(rng, states)
        x[6:10] *= 1.02                                       # a non-unit mean quaternion too
        u = imu(rng)
        np.testing.assert_allclose(fast.f(x, u, dt), slow.f(x, u, dt), atol=1e-14)
        np.testing.assert_allclose(fast.jacobian(x, u, dt), slow.jacobian(x, u, dt), atol=1e-14)
        np.testing.assert_allclose(fast.Q(x, u, dt), slow.Q(x, u, dt), atol=1e-18)


@pytest.mark.parametrize("states", [10, 22])
def test_state_sets_report_the_eta_clamp_as_the_16_state_model(states):
    """The 10/22-state models delegate step_events to the 16-state core: the same clamps, counted by the run."""
    from fusion.api import ReportsStepEvents, has

    m = make(states=states, eta=50.0)
    assert has(m, ReportsStepEvents)
    dts = np.array([0.01, 0.05, 0.01, 0.02])                    # eta dt: 0.5, 2.5, 0.5, 1.0
    assert [e.kind for e in m.step_events(1.0, dts)] == [e.kind for e in make(eta=50.0).step_events(1.0, dts)]
    assert len(m.step_events(1.0, dts)) == 2 and make(states=states).step_events(1.0, dts) == ()


@pytest.mark.parametrize("states", [10, 16, 22])
def test_a_sample_held_past_hold_after_is_integrated_over_hold_after_then_the_state_coasts(states):
    """A 10 s pause of every stream during a turn, predicted by integrating the last IMU sample (the
    turn's yaw rate) over the 10 s, would give 27-40 deg of attitude error and every GPS fix gated out. Past
    hold_after the sample is no estimate of the input: attitude, velocity and sensor states are kept and
    p += v e over the excess e; F agrees (numerical Jacobian) and a run of samples with the gap too."""
    rng = np.random.default_rng(8)
    m = make(states=states, hold_after=0.03)
    x, u = random_state(rng, states), imu(rng)
    short = m.f(x, u, 0.03)
    long = m.f(x, u, 10.0)
    np.testing.assert_array_equal(long[3:], short[3:])                   # no rotation, no velocity change past 0.03 s
    np.testing.assert_allclose(long[:3], short[:3] + 9.97 * short[3:6], rtol=1e-12)
    Fn = numerical_jacobian(lambda X: m.f(X, u, 10.0), x)
    np.testing.assert_allclose(m.jacobian(x, u, 10.0), Fn, atol=2e-6 * max(1.0, np.abs(Fn).max()))
    us = np.array([imu(rng) for _ in range(4)])
    dts = np.array([0.02, 10.0, 0.02, 0.02])
    ref = x
    for ui, dt in zip(us, dts):
        ref = m.f(ref, ui, dt)
    np.testing.assert_allclose(m.f_inputs(x[None], us, dts)[0], ref, atol=1e-12)
    plain = make(states=states)                                          # no hold_after: the sample over dt
    assert not np.allclose(plain.f(x, u, 10.0)[6:10], x[6:10], atol=1e-3)


def test_the_hold_noise_covers_the_excess_time_and_its_attitude_sd_is_bounded():
    m = make(states=22, hold_after=0.03, hold_max_attitude_sd=0.5)     # defaults: yaw 0.3, tilt 0.02 rad/s, tau 2 s
    x = random_state(np.random.default_rng(9), 22)
    x[6:10] = quat.normalize(x[6:10])
    q0, q1, q2, q3 = x[6:10]
    Xi = np.array([[-q1, -q2, -q3], [q0, q3, -q2], [-q3, q0, q1], [q2, -q1, q0]])   # [0, dth_n] (x) q = Xi dth_n

    def gm(sd, e):                                                   # integral of a Gauss-Markov rate (tau 2 s)
        return 2 * sd * sd * 4.0 * (e / 2.0 - 1 + np.exp(-e / 2.0))

    for dt, want in ((0.5, np.sqrt([gm(0.02, 0.47), gm(0.02, 0.47), gm(0.3, 0.47)])),
                     (10.0, [np.sqrt(gm(0.02, 9.97)), np.sqrt(gm(0.02, 9.97)), 0.5])):   # heading: the bound
        Q = m.Q(x, imu(np.random.default_rng(1)), dt)
        P_theta = 4.0 * Xi.T @ Q[6:10, 6:10] @ Xi                     # navigation-frame attitude error (N E D)
        # the gyro's own white noise adds ~1e-4 rad: within the tolerance
        np.testing.assert_allclose(np.sqrt(np.diag(P_theta)), want, rtol=0.05, atol=2e-4)
        assert np.sqrt(Q[3, 3]) >= np.sqrt(gm(1.0, dt - 0.03))          # velocity: the acceleration's integral
