"""The white_acceleration trajectory: a walk of the constant-velocity model, checked against the model's own
statistics (the velocity increments over dt have variance q dt and are independent; position and velocity
increments have the covariance Q(dt) of the pv process), its derivatives, its bounds and its errors."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import parse_log, run_yaml, table

from fusion.api import ConfigError
from fusion.simulate import parse_scenario
from fusion.simulate.trajectory import TrajectoryError, build_trajectory
from fusion.simulate.white_acceleration import transition


def _walk(body: str, dim: int = 2):
    sc = parse_scenario(f"""
dim: {dim}
trajectory: {{type: white_acceleration, {body}}}
sensors: {{p: {{type: position}}}}
""")
    return build_trajectory(sc.trajectory, sc.dim, sc.duration)


def test_increments_have_the_models_covariance():
    q, dt = 0.2, 0.05
    tr = _walk(f"spectral_density: {q}, start: [0, 0], duration: 2000, step: 0.01, seed: 4")
    t = np.arange(0.0, 2000.0, dt)
    k = tr.sample(t)
    dv = np.diff(k.v[:, :2], axis=0)                      # (N, 2): both axes, independent by the model
    dp = np.diff(k.p[:, :2], axis=0) - dt * k.v[:-1, :2]  # the part of the position step the noise makes
    n = dv.size
    tol = 5.0 * np.sqrt(2.0 / n)                          # 5 sd of a variance estimate, relative
    assert np.var(dv) == pytest.approx(q * dt, rel=tol)
    _, Q = transition(q, dt)
    X = np.stack([dp.ravel(), dv.ravel()])
    C = X @ X.T / n
    assert C[0, 0] == pytest.approx(Q[0, 0], rel=tol)
    assert C[0, 1] == pytest.approx(Q[0, 1], rel=2 * tol)
    # white: successive increments uncorrelated, the axes too
    for a in range(2):
        r = np.corrcoef(dv[1:, a], dv[:-1, a])[0, 1]
        assert abs(r) < 5.0 / np.sqrt(len(dv))
    assert abs(np.corrcoef(dv[:, 0], dv[:, 1])[0, 1]) < 5.0 / np.sqrt(len(dv))
    assert abs(dv.mean()) < 5.0 * np.sqrt(q * dt / n)


def test_derivatives_between_grid_points_and_grid_values():
    tr = _walk("spectral_density: 1.0, start: [1, 2, 3], start_velocity: [0.5, 0, -0.5], duration: 5, "
               "step: 0.02, seed: 1", dim=3)
    t = np.arange(0.001, 4.99, 0.0037)
    h = 1e-6
    t = t[np.abs(t / 0.02 - np.round(t / 0.02)) * 0.02 > 3 * h]   # the acceleration jumps at grid points
    k, kp, km = tr.sample(t), tr.sample(t + h), tr.sample(t - h)
    assert np.abs((kp.p - km.p) / (2 * h) - k.v).max() < 1e-6
    assert np.abs((kp.v - km.v) / (2 * h) - k.a).max() < 1e-5
    tg, P, V = tr.grid()
    g = tr.sample(tg)
    assert np.allclose(g.p, P) and np.allclose(g.v, V)
    assert np.all(g.euler == 0.0) and np.all(g.w_b == 0.0)
    assert np.allclose(P[0], [1, 2, 3]) and np.allclose(V[0], [0.5, 0, -0.5])


def test_initial_state_is_drawn_from_the_prior():
    starts = np.array([_walk(f"spectral_density: 0.2, start: [3, 3], start_sd: 1.0, start_velocity_sd: 0.5, "
                             f"duration: 0.05, seed: {s}").grid()[1:] for s in range(400)])   # (seeds, 2, n, 2)
    p0, v0 = starts[:, 0, 0, :], starts[:, 1, 0, :]
    assert np.abs(p0.mean(axis=0) - 3.0).max() < 5 * 1.0 / np.sqrt(400)
    assert p0.std() == pytest.approx(1.0, rel=0.1)
    assert v0.std() == pytest.approx(0.5, rel=0.1)


def test_redraw_keeps_the_walk_in_the_hall_and_is_reproducible():
    spec = ("spectral_density: 0.2, start: [3, 3], start_sd: 1.0, start_velocity_sd: 0.5, duration: 15, "
            "bounds: [[0, 30], [0, 20]], boundary: redraw, seed: 7")
    tr = _walk(spec)
    _, P, _ = tr.grid()
    assert np.all(P >= 0) and np.all(P[:, 0] <= 30) and np.all(P[:, 1] <= 20)
    assert tr.draws >= 1
    again = _walk(spec)
    assert again.draws == tr.draws and np.array_equal(again.grid()[1], P)
    assert not np.array_equal(_walk(spec.replace("seed: 7", "seed: 8")).grid()[1], P)


def test_reflect_folds_the_walk_into_the_area():
    tr = _walk("spectral_density: 2.0, start: [5, 5], duration: 60, bounds: [[0, 10], [0, 10]], "
               "boundary: reflect, seed: 2")
    t = np.arange(0.0, 60.0, 0.013)
    k = tr.sample(t)
    assert np.all(k.p[:, :2] >= 0) and np.all(k.p[:, :2] <= 10)
    _, P, _ = tr.grid()
    assert np.abs(P).max() > 10      # the free walk left the area: the fold did the work
    h = 1e-6   # the velocity flips at a wall: its derivative checked away from the walls
    inside = np.all((k.p[:, :2] > 0.1) & (k.p[:, :2] < 9.9), axis=1)
    d = (tr.sample(t + h).p - tr.sample(t - h).p) / (2 * h)
    assert np.abs(d[inside] - k.v[inside]).max() < 1e-4


def test_a_recording_on_the_walk_and_the_scenario_seed():
    yaml = """
dim: 2
beacons: {A: [0, 0], B: [30, 0]}
trajectory: {type: white_acceleration, spectral_density: 0.2, start: [3, 3], duration: 5, seed: 3}
truth: {rate_hz: 20}
sensors: {uwb: {type: range, rate_hz: 5, noise_sd: 0.1}}
"""
    a, b = run_yaml(yaml, seed=1), run_yaml(yaml, seed=2)
    ta, tb = table(parse_log(a)[0]["truth"]), table(parse_log(b)[0]["truth"])
    assert np.array_equal(ta, tb)                # the walk follows its own seed, not the scenario's
    assert a != b                                # the ranges' noise follows the scenario's
    assert ta[-1, 0] == pytest.approx(5.0)


@pytest.mark.parametrize("body, message", [
    ("spectral_density: 0.2, start: [0, 0, 0], duration: 5", "2-D scenario has 2 coordinates"),
    ("spectral_density: 0.2, start: [0, 0], start_velocity: [1], duration: 5", "start_velocity"),
    ("spectral_density: 0.2, start: [50, 0], duration: 5, bounds: [[0, 30], [0, 20]]", "outside"),
    ("spectral_density: 0.2, start: [5, 5], duration: 5, bounds: [[0, 30]]", "bounds"),
    ("spectral_density: 50, start: [1, 1], duration: 30, bounds: [[0, 2], [0, 2]], max_draws: 3", "max_draws"),
])
def test_bad_walks_are_explained(body, message):
    with pytest.raises(TrajectoryError, match=message):
        _walk(body)


def test_the_spec_is_validated():
    with pytest.raises(ConfigError, match="spectral_density"):
        parse_scenario("trajectory: {type: white_acceleration, start: [0, 0, 0], duration: 5}\n"
                       "sensors: {p: {type: position}}\n")
    with pytest.raises(ConfigError, match="boundary"):
        parse_scenario("trajectory: {type: white_acceleration, spectral_density: 1, start: [0, 0, 0], duration: 5, "
                       "boundary: wrap}\nsensors: {p: {type: position}}\n")
    with pytest.raises(ConfigError, match="longer than trajectory.duration"):
        run_yaml("duration: 10\ntrajectory: {type: white_acceleration, spectral_density: 1, start: [0, 0, 0], "
                 "duration: 5}\nsensors: {p: {type: position}}\n")
