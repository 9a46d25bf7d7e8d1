"""Trajectories: position, velocity, acceleration, attitude and angular rate are mutually consistent."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import parse_scenario

from fusion.simulate.kinematics import euler_rates_to_body
from fusion.simulate.trajectory import TrajectoryError, build_trajectory


def _traj(yaml: str):
    sc = parse_scenario(yaml)
    return build_trajectory(sc.trajectory, sc.dim, sc.duration), sc


def _check_derivatives(tr, t):
    h = 1e-6  # central differences: error h^2 where smooth, h * (jump of the jerk) / 4 where the jerk jumps
    k, kp, km = tr.sample(t), tr.sample(t + h), tr.sample(t - h)
    assert np.abs((kp.p - km.p) / (2 * h) - k.v).max() < 5e-5
    assert np.abs((kp.v - km.v) / (2 * h) - k.a).max() < 5e-5
    assert np.abs((kp.euler - km.euler) / (2 * h) - k.euler_rate).max() < 5e-5
    return k


def test_waypoint_trajectory_is_consistent_and_smooth(yaml_3d_turning):
    tr, sc = _traj(yaml_3d_turning)
    t = np.arange(0.0, tr.duration, 0.002)
    k = _check_derivatives(tr, t)
    # continuous acceleration: no jump between samples 2 ms apart larger than jerk-limited change
    assert np.abs(np.diff(k.a, axis=0)).max() < 0.02
    assert np.abs(np.diff(k.p, axis=0)).max() <= 3.0 * 0.002 * 1.01  # no teleport
    # heading along the horizontal velocity, pitch along the slope, no roll
    v_h = np.hypot(k.v[:, 0], k.v[:, 1])
    m = v_h > 1e-3
    dpsi = np.angle(np.exp(1j * (np.arctan2(k.v[m, 1], k.v[m, 0]) - k.euler[m, 2])))
    assert np.abs(dpsi).max() < 1e-9
    assert np.allclose(np.tan(k.euler[m, 1]), -k.v[m, 2] / v_h[m])
    assert np.all(k.euler[:, 0] == 0.0)
    # static start: at rest at the first waypoint
    rest = t < sc.trajectory.static_start
    assert np.all(k.v[rest] == 0) and np.allclose(k.p[rest], [0, 0, 0])
    # the stop: at rest for 2 s somewhere (speed exactly zero), not at the start
    still = (np.linalg.norm(k.v, axis=1) == 0) & (t > 3.01) & (t < tr.duration - 0.1)
    assert 1.9 < still.sum() * 0.002 < 2.1
    assert np.ptp(k.p[still], axis=0).max() == 0.0
    # cruise speed reached, and the slow corner driven at its turn speed
    assert v_h.max() == pytest.approx(3.0, abs=1e-9)
    kappa = np.abs(k.euler_rate[m, 2]) / v_h[m]      # radius-2 corner: |kappa| up to 0.5; others 0.25
    assert np.allclose(v_h[m][kappa > 0.3], 1.5)


def test_straight_legs_follow_the_waypoint_polyline():
    tr, _ = _traj("""
dim: 2
trajectory: {type: waypoints, radius: 1.0, waypoints: [[0, 0], [10, 0], [10, 10], [0, 10]]}
sensors: {p: {type: position}}
""")
    s = np.linspace(0, tr.path.length, 2001)
    xy = tr.path.position(s)
    # every point is within the corner cut of the polyline, and the leg middles lie on it exactly
    assert tr.path.position(np.array([tr.path.stations[0] + 4.0]))[0] == pytest.approx([4.0, 0.0], abs=1e-12)
    assert np.allclose(tr.path.position(np.array([tr.path.length])), [[0.0, 10.0]], atol=1e-9)
    d = np.minimum.reduce([np.abs(xy[:, 1]), np.abs(xy[:, 0] - 10), np.abs(xy[:, 1] - 10)])
    assert d.max() < 0.5
    # peak curvature is 1 / radius
    _, kap, _ = tr.path.heading(s)
    assert np.abs(kap).max() == pytest.approx(1.0, rel=1e-3)


def test_random_walk_is_consistent_and_bounded():
    tr, _ = _traj("""
dim: 3
duration: 60
trajectory: {type: random_walk, start: [1.5, 1.5, 1.5], step_interval: 0.225, position_step_sd: 0.05,
             angle_step_sd_deg: 3, bounds: [[0.5, 2.5], [0.5, 2.5], [0.5, 2.5]], static_start: 1.0}
sensors: {p: {type: position}}
""")
    t = np.arange(0.0, 60.0, 0.01)
    k = _check_derivatives(tr, t)
    assert np.all(k.p > 0.45) and np.all(k.p < 2.55)
    assert np.all(k.v[t < 1.0] == 0.0)
    w = euler_rates_to_body(k.euler, k.euler_rate)
    assert np.allclose(w, k.w_b)
    q = k.q
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0)
    assert np.all(np.einsum("ij,ij->i", q[1:], q[:-1]) > 0)  # sign-continuous


@pytest.mark.parametrize("waypoints, message", [
    ("[[0, 0], [1, 0], [1, 1]]", "too short for the turns"),
    ("[[0, 0], [10, 0], [0, 0.1]]", "turns back on itself"),
    ("[[0, 0], [0, 0]]", "coincide"),
])
def test_bad_waypoints_are_explained(waypoints, message):
    sc = parse_scenario(f"""
dim: 2
trajectory: {{type: waypoints, radius: 3.0, waypoints: {waypoints}}}
sensors: {{p: {{type: position}}}}
""")
    with pytest.raises(TrajectoryError, match=message):
        build_trajectory(sc.trajectory, 2, None)
