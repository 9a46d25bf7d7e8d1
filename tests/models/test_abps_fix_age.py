"""The age of an ABPS fix: a cycle closes at its last heard slot, the compensation and the
bridge carry the acceleration over the age, and the opt-in second-order bridge from the IMU.

A fix is of the cycle's mean range time t_m; the filter may have integrated inputs past t_m, so the fix is
applied ``age`` s later and the position model bridges it back (p - v age). Each check below builds its own
input (a firing stream, an analytic trajectory) and compares with that generator's truth or an independent
construction.
"""
from __future__ import annotations

import numpy as np
import pytest

from fusion import quaternion as quat
from fusion.api import BuildContext, Fix, Message, StateLayout, UsesInput
from fusion_plugins.measurement.position import AgedPosition, ImuAgedPosition, Position, PositionParams
from fusion_plugins.solvers.firing_schedule import FiringSchedule
from fusion_plugins.solvers.ols_trilateration import OlsParams, OlsTrilateration
from fusion_plugins.solvers.range_fix import Cycle, range_cov

INS = StateLayout.parse("p:3 v:3 q:4:quaternion ba:3 bw:3")
C = 343.0
# 12 beacons along a drift, on alternating walls, firing in that order 35 ms apart every 0.5 s
DRIFT = {f"D{i + 1}": np.array([4.0 * i, 0.1 if i % 2 == 0 else 2.9, -0.9]) for i in range(12)}


def stream(route, period=0.5, spacing=0.035, n_cycles=8, reach=12.0):
    """Beacon j of cycle n fires at 0.1 + n period + j spacing; arrival after the time of flight. Returns
    [(t_arrival, beacon, range, cycle)], only the beacons within ``reach``."""
    out = []
    for n in range(n_cycles):
        for j, name in enumerate(DRIFT):
            te = 0.1 + n * period + j * spacing
            ta = te
            for _ in range(8):
                ta = te + np.linalg.norm(route(ta) - DRIFT[name]) / C
            r = float(np.linalg.norm(route(ta) - DRIFT[name]))
            if r <= reach:
                out.append((ta, name, r, n))
    return sorted(out)


# --------------------------------------------------------------------------- 1. closing at the last heard slot
@pytest.mark.parametrize("close", [True, False])
def test_a_cycle_closes_at_its_last_heard_slot(close):
    """A receiver standing at x = 6 m hears D1-D5 of the 12 beacons. From the second cycle on its fix comes
    out with the range of D5 (its last heard slot), not with D1's range of the next cycle ~0.36 s later: the
    filter's belief is then no later than the cycle's last range. (close_at_last_slot=False: the old rule.)"""
    x = np.array([6.0, 1.5, -0.75])
    s = OlsTrilateration(OlsParams(z=-0.75, z_sd=0.0, firing_period=0.5, speed_of_sound=C,
                                   close_at_last_slot=close), BuildContext(beacons=DRIFT, sensor="abps"))
    msgs = stream(lambda t: x)
    assert {b for _, b, _, _ in msgs} == {"D1", "D2", "D3", "D4", "D5"}
    emitted_by = []                  # (time of the message whose feed emitted a fix, last range of its cycle)
    for t, b, r, n in msgs:
        for _ in s.feed(Message(t, "abps", (b, r))):
            last = max(tt for tt, _, _, nn in msgs if nn == s.counters["fixes"] - 1)
            emitted_by.append((t, last))
    assert s.counters["fixes"] == len(emitted_by) >= 6
    if close:
        assert all(t == last for t, last in emitted_by[1:])               # at the cycle's own last range
        assert emitted_by[0][0] > emitted_by[0][1] + 0.3                  # the first cycle: no history yet
    else:
        assert all(t > last + 0.3 for t, last in emitted_by)


def test_a_beacon_missing_for_a_while_then_back_in_a_later_slot_loses_one_range():
    """Five beacons; E5 (the last slot) is not heard in cycles 2-4. Cycles 2 and 3 still expect it (heard in
    the last EXPECT_CYCLES = 3 cycles) and close at the next cycle's first range, as without the option;
    cycle 4 no longer does and closes at E4. When E5 is back (cycle 5) its range comes after its cycle was
    closed at E4: dropped (take_late), and from cycle 6 on it is expected again. No other range is lost."""
    names = ["E1", "E2", "E3", "E4", "E5"]
    sched = FiringSchedule(0.5, close_at_last_slot=True, learn_s=0.5)
    closed_at, n_ranges = [], 0
    for n in range(8):
        for j, b in enumerate(names):
            if b == "E5" and 2 <= n <= 4:
                continue
            t = 0.1 + 0.5 * n + 0.035 * j
            n_ranges += 1
            for cyc in sched.add(t, b, 3.0 + j):
                closed_at.append(((n, b), [c[1] for c in cyc]))
    closed_at += [(None, [c[1] for c in cyc]) for cyc in sched.flush()]
    late = sched.take_late()
    assert [(b, round(t, 6)) for t, b, _, _ in late] == [("E5", round(0.1 + 2.5 + 0.14, 6))]
    assert closed_at == [((1, "E1"), names),            # the first cycle: no history, closed by the next one
                         ((1, "E5"), names),            # at its last slot
                         ((3, "E1"), names[:4]),        # E5 still expected: closed by the next cycle
                         ((4, "E1"), names[:4]),
                         ((4, "E4"), names[:4]),        # E5 forgotten: closed at E4
                         ((5, "E4"), names[:4]),        # E5 comes after this: late
                         ((6, "E5"), names),            # expected again
                         ((7, "E5"), names)]
    assert sum(len(c) for _, c in closed_at) + len(late) == n_ranges


def test_a_second_report_of_a_closed_cycle_pulse_is_a_duplicate_not_late():
    sched = FiringSchedule(0.5, speed_of_sound=None, close_at_last_slot=True, learn_s=0.5)
    out = []
    for n in range(3):
        for j, b in enumerate(["D1", "D2", "D3"]):
            out += sched.add(0.1 + 0.5 * n + 0.035 * j, b, 5.0 + j)
    out += sched.add(0.1 + 1.0 + 0.07 + 1e-4, "D3", 7.2)                  # D3 of cycle 2 again, longer (an echo)
    assert [len(c) for c in out] == [3, 3, 3]
    assert sched.take_late() == [] and len(sched.take_duplicates()) == 1


# --------------------------------------------------------------------------- 2. the acceleration over the age
def test_the_compensation_covariance_carries_the_velocity_of_the_belief_time():
    """Ranges at t_m + dt_i referred to t_m with the velocity of t_m + age: for an acceleration a the
    receiver moved a (dt^2 / 2 - age dt) more than assumed, so range i errs by u_i . a (dt_i^2/2 - age dt_i).
    range_cov's acceleration term equals the covariance of those errors for a ~ N(0, s^2 I), formed here
    independently as s^2 A A^T."""
    rng = np.random.default_rng(1)
    U = rng.normal(size=(6, 3))
    U /= np.linalg.norm(U, axis=1, keepdims=True)
    dt = np.linspace(-0.09, 0.09, 6)
    s, age = 0.7, 0.23
    A = U * (0.5 * dt * dt - age * dt)[:, None]
    cyc = Cycle(np.zeros((6, 3)), np.ones(6), dt, np.zeros((3, 3)), s, 0.0, age)
    got = range_cov(U, cyc, np.arange(6), 1e-3) - 1e-6 * np.eye(6)
    np.testing.assert_allclose(got, s * s * A @ A.T, atol=1e-15)


def test_the_bridge_adds_the_acceleration_it_leaves_out_to_R():
    m = Position(PositionParams(lever_arm=(0.2, 0.0, -0.4), accel_sd=0.5), BuildContext(layout=INS))
    cov = np.diag([4e-4, 9e-4, 2.5e-3])
    obs = m.observe(Fix(10.0, np.array([1.0, 2.0, -0.7]), cov, 0.3))
    np.testing.assert_allclose(obs.R, cov + (0.5 * 0.5 * 0.3 ** 2) ** 2 * np.eye(3), rtol=0, atol=1e-18)
    assert isinstance(obs.model, AgedPosition) and not isinstance(obs.model, ImuAgedPosition)
    np.testing.assert_array_equal(m.observe(Fix(10.0, np.zeros(3), cov, 0.0)).R, cov)   # no age: the fix's


# --------------------------------------------------------------------------- 3. the second-order bridge (IMU)
ARM = np.array([0.2, 0.1, -0.4])
A_N = np.array([-3.0, 0.5, 0.0])          # m/s^2, navigation frame: hard braking with a side component
WZ = 1.2                                  # rad/s: turning
BA, BW = np.array([0.01, -0.02, 0.03]), np.array([0.001, 0.002, -0.003])


def _state(t):
    p = np.array([1.0, 2.0, -0.3]) + np.array([2.0, 0.3, 0.0]) * t + 0.5 * A_N * t * t
    v = np.array([2.0, 0.3, 0.0]) + A_N * t
    yaw = 0.3 + WZ * t
    return np.r_[p, v, np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2), BA, BW]


def _receiver(x):
    return x[:3] + quat.rotate(x[6:10], ARM)


def _imu(x):
    """The IMU sample of state x: specific force C_n^b (a - g_n) + b_a, rate w + b_w (FRD)."""
    Cnb = quat.to_matrix(x[6:10]).T
    return np.r_[Cnb @ (A_N - np.array([0.0, 0.0, 9.80665])) + BA, np.array([0.0, 0.0, WZ]) + BW]


@pytest.mark.parametrize("age", [0.1, 0.3, 0.5])
def test_the_imu_bridge_is_exact_to_the_jerk_and_the_first_order_one_is_not(age):
    """An analytic trajectory (constant acceleration in the navigation frame while turning at 1.2 rad/s, a
    lever arm): the true state at the update time predicts the true receiver position ``age`` s earlier to
    third order with the imu bridge (< 2 mm at 0.3 s: the lever arm's turn), while p - v age misses it by a age^2 / 2 and the
    turn of the lever arm (decimetres)."""
    t = 5.0
    x, target = _state(t), _receiver(_state(t - age))
    first = Position(PositionParams(lever_arm=tuple(ARM)), BuildContext(layout=INS))
    imu = Position(PositionParams(lever_arm=tuple(ARM), bridge="imu"), BuildContext(layout=INS))
    imu.take_input(t, _imu(x))
    fix = Fix(t, target, 1e-4 * np.eye(3), age)
    e1 = np.linalg.norm(first.observe(fix).model.h(x) - target)
    m2 = imu.observe(fix).model
    e2 = np.linalg.norm(m2.h(x) - target)
    assert isinstance(m2, ImuAgedPosition)
    # what is left: the lever arm's turn to third order, |r_xy| (w age)^3 / 6 (a is constant here)
    assert e1 > 0.4 * np.linalg.norm(A_N) * age ** 2 and e2 < 1.01 * np.hypot(*ARM[:2]) * (WZ * age) ** 3 / 6
    # position_from inverts h
    np.testing.assert_allclose(m2.h(np.r_[m2.position_from(target, x), x[3:]]), target, atol=1e-12)


def test_the_imu_bridge_jacobian_and_batches():
    """Analytic Jacobian against central differences (biases and attitude included: the bridge's specific
    force and rate are the state's bias-corrected ones), and h on a batch equals h per state."""
    t, age = 3.0, 0.35
    x = _state(t)
    m = Position(PositionParams(lever_arm=tuple(ARM), bridge="imu"), BuildContext(layout=INS))
    m.take_input(t, _imu(x) + np.array([0.1, -0.2, 0.05, 0.3, -0.2, 0.1]))
    model = m.observe(Fix(t, np.zeros(3), np.eye(3), age)).model
    eps = 1e-6
    Hn = np.column_stack([(model.h(x + eps * e) - model.h(x - eps * e)) / (2 * eps) for e in np.eye(16)])
    np.testing.assert_allclose(model.jacobian(x), Hn, atol=1e-8)
    X = x + np.random.default_rng(2).normal(scale=0.05, size=(9, 16))
    np.testing.assert_allclose(model.h(X), np.array([model.h(xi) for xi in X]), atol=1e-14)


def test_the_model_reads_the_inputs_only_with_the_imu_bridge():
    """fusion.api.UsesInput makes the scheduler integrate the inputs up to every message of the sensor (a
    cost): only the imu bridge declares it; before its first sample the bridge is first order."""
    first = Position(PositionParams(lever_arm=tuple(ARM)), BuildContext(layout=INS))
    imu = Position(PositionParams(lever_arm=tuple(ARM), bridge="imu"), BuildContext(layout=INS))
    assert not isinstance(first, UsesInput) and isinstance(imu, UsesInput)
    obs = imu.observe(Fix(1.0, np.zeros(3), np.eye(3), 0.2))
    assert type(obs.model) is AgedPosition


def test_the_imu_acceleration_refers_the_ranges_with_the_velocity_of_the_cycle_time():
    """Hard braking (3 m/s^2) at 2.5 m/s, noise-free ranges of D1-D5; the belief comes back 0.15 s after the
    cycle's mean time with the true velocity and position then. Referring the ranges with that velocity
    errs by a (dt^2/2 - age dt) per range; with ``input_acceleration`` (the IMU's specific force, level
    attitude) the velocity at the mean time and a dt^2 / 2 are used and the fix is exact (to rounding, against
    the generator's receiver at t - age); without, 3.4 mm off."""
    from fusion.api import Belief

    a = np.array([-3.0, 0.0, 0.0])
    v0 = np.array([2.5, 0.0, 0.0])
    late = 0.15
    route = lambda t: np.array([6.0, 1.5, -0.75]) + v0 * t + 0.5 * a * t * t      # noqa: E731
    msgs = [m for m in stream(route, n_cycles=3) if m[3] < 2]                      # ~0.8 s: still moving

    def belief(t):
        x = np.zeros(16)
        x[0:3], x[3:6], x[6] = route(t + late), v0 + a * (t + late), 1.0
        return Belief(t + late, x, P=np.eye(16) * 1e-6)

    errs = {}
    for imu in (False, True):
        s = OlsTrilateration(OlsParams(z=-0.75, z_sd=0.0, firing_period=0.5, speed_of_sound=C, refine_iterations=3,
                                       motion_compensation=True, input_acceleration=imu),
                             BuildContext(layout=INS, beacons=DRIFT, sensor="abps"))
        assert isinstance(s, UsesInput) is imu
        s.bind_belief(belief)
        if imu:
            s.take_input(0.0, np.r_[a - np.array([0.0, 0.0, 9.80665]), 0.0, 0.0, 0.0])   # f = C_n^b (a - g_n)
        fixes = [f for t, b, r, _ in msgs for f in s.feed(Message(t, "abps", (b, r)))] + s.flush()
        assert len(fixes) == 2 and all(f.age == pytest.approx(late) for f in fixes)
        errs[imu] = max(np.linalg.norm(f.value[:2] - route(f.t - f.age)[:2]) for f in fixes)
    assert errs[True] < 1e-9 and errs[False] > 2e-3                 # 3.4 mm without
