"""Paper 003 orientation: orientation_geometric (eqs. 12-17) against scipy's Rotation on exact directions,
the direction model (eq. 19) against Rotation, its Jacobians, the quaternion random walk of
static_orientation against sampled rotations, and the pose pieces (firing_clock with attitude, pose fix)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion import quaternion as quat
from fusion import testing
from fusion.api import BuildContext, ConfigError, MalformedMessage, Message
from fusion_plugins.solvers.orientation_geometric import (axis_rotation, best_pair, orientation_fix,
                                                          two_vector_attitude)
from fusion_plugins.solvers.tdoa_geometric import NoFix

LAB = {"B1": [0, 0, 0], "B2": [2.6, 0, 0], "B3": [0, 2.6, 0], "B4": [0, 0, 2.6]}
BEACONS = {k: np.array(v, float) for k, v in LAB.items()}


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@pytest.mark.parametrize("seed", range(6))
def test_axis_rotation_is_the_rotation_about_v_cross_vref(seed):
    rng = np.random.default_rng(seed)
    v, w = _unit(rng.normal(size=(2, 3)))
    if seed == 4:                                # the axis v x w along x: R_x of eq. 13 degenerates
        v, w = np.array([0.0, 0.6, 0.8]), np.array([0.0, -0.8, 0.6])
    axis = np.cross(v, w)
    ref = Rotation.from_rotvec(_unit(axis) * np.arctan2(np.linalg.norm(axis), v @ w)).as_matrix()
    T = axis_rotation(v, w)
    assert np.abs(T - ref).max() < 1e-12 and np.abs(T @ v - w).max() < 1e-12


def test_axis_rotation_edge_cases():
    v = _unit(np.array([0.2, -0.5, 0.7]))
    assert np.allclose(axis_rotation(v, v), np.eye(3))
    T = axis_rotation(v, -v)
    assert np.allclose(T @ v, -v) and np.allclose(T @ T.T, np.eye(3)) and np.isclose(np.linalg.det(T), 1.0)


@pytest.mark.parametrize("seed", range(8))
def test_orientation_fix_is_exact_on_exact_directions(seed):
    rng = np.random.default_rng(100 + seed)
    rot = Rotation.random(random_state=seed)
    b = _unit(rng.normal(size=(4, 3)))           # navigation-frame directions to four beacons
    n = rot.inv().apply(b)                       # the same directions in the body frame (exact)
    C = orientation_fix(n, b)
    assert np.abs(C - rot.as_matrix()).max() < 1e-12
    C2 = two_vector_attitude(n[0], n[2], b[0], b[2])
    assert np.abs(C2 - rot.as_matrix()).max() < 1e-12


def test_bisectors_share_the_error_of_unequal_angles():
    """Eq. 17: when the two angles differ (discretised normals), both vectors end equally far from theirs."""
    rng = np.random.default_rng(3)
    b = _unit(rng.normal(size=(2, 3)))
    n = _unit(b + rng.normal(0, 0.1, (2, 3)))
    C = two_vector_attitude(n[0], n[1], b[0], b[1])
    e = np.arccos(np.clip(np.einsum("ij,ij->i", (C @ n.T).T, b), -1, 1))
    assert abs(e[0] - e[1]) < 1e-9


def test_pair_choice_and_degenerate_cycle():
    n = np.array([[1.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])       # beacons 1 and 2: one receiver
    b = _unit(np.array([[1.0, 0.1, 0], [1.0, 0, 0.1], [0, 1.0, 0], [0, 0.1, 1.0]]))
    i, j = best_pair(n, b)
    assert {i, j} != {0, 1}
    with pytest.raises(NoFix) as err:
        orientation_fix(np.tile([0.0, 0, 1], (4, 1)), b)
    assert err.value.reason == "degenerate"


def test_orientation_solver_component():
    """A cycle of four exact arrivals: the solver's TDOA position and attitude from the closest receivers."""
    from fusion_plugins.measurement.direction import receiver_normals as _normals
    ctx = BuildContext(beacons=BEACONS, sensor="us")
    s = testing.build("solver", "orientation_geometric", {"receivers": "truncated_icosahedron"}, ctx)
    r, rot = np.array([1.2, 1.1, 1.4]), Rotation.from_euler("xyz", [10, -20, 30], degrees=True)
    N = _normals("truncated_icosahedron")
    out = []
    for k, (name, b) in enumerate(BEACONS.items()):
        a = 0.1 + 0.225 * k + np.linalg.norm(r - b) / 340.0
        rec = int(np.argmax(N @ rot.inv().apply(_unit(b - r)))) + 1
        out += s.feed(Message(a, "us", (name, a, float(rec))))
    assert len(out) == 1 and out[0].value.shape == (3,) and out[0].attitude_cov.shape == (3, 3)
    q, pos = out[0].attitude, out[0].value
    assert np.abs(pos - r).max() < 1e-8
    assert np.rad2deg(quat.angle_between(q, rot.as_quat(scalar_first=True))) < 30.0   # discretised directions
    assert s.feed(Message(9.0, "us", ("B1", 9.0, 33.0))) == [] and s.counters["malformed"] == 1
    assert "receiver must be 1-32" in s.events[-1].detail


# --------------------------------------------------------------------------- direction model
def _direction(layout, **params):
    params.setdefault("receivers", "truncated_icosahedron")    # the numbering the tests' receivers use
    return testing.build("measurement", "direction", params, BuildContext(layout=layout, beacons=BEACONS))


@pytest.mark.parametrize("seed", range(4))
def test_direction_is_eq_19_against_rotation(seed):
    rng = np.random.default_rng(seed)
    proc = testing.build("process", "firing_clock", {"attitude_sd_deg": 0.57})
    model = _direction(proc.layout)
    obs = model.observe(Message(1.0, "us", ("B3", 1.0, 7.0)))
    rot = Rotation.random(random_state=seed)
    p = rng.uniform(0.5, 2.5, 3)
    x = np.r_[p, 0.225, 0.9, rot.as_quat(scalar_first=True)]
    ref = rot.inv().apply(_unit(BEACONS["B3"] - p))
    assert np.abs(obs.model.h(x) - ref).max() < 1e-12
    # default: the position estimate feeds the model but the directions do not update it (dh/dp left out)
    from fusion_plugins.filters.jacobian import numerical_jacobian
    H, Hn = obs.model.jacobian(x), numerical_jacobian(obs.model.h, x)
    assert not H[:, :5].any() and np.abs(H[:, 5:] - Hn[:, 5:]).max() < 1e-6
    full = _direction(proc.layout, position_from_direction=True).observe(Message(1.0, "us", ("B3", 1.0, 7.0)))
    assert testing.check_measurement_jacobian(full.model, x) < 1e-6
    assert np.allclose(obs.z, model.normals[6]) and obs.R.shape == (3, 3)
    pose = _direction(proc.layout, arrival=True, position_from_direction=True)
    o4 = pose.observe(Message(1.0, "us", ("B3", 1.0, 7.0)))
    assert o4.z.shape == (4,) and o4.model.h(x)[0] == pytest.approx(0.9 + np.linalg.norm(p - BEACONS["B3"]) / 340.0)
    assert testing.check_measurement_jacobian(o4.model, x) < 1e-6


def test_direction_noise_is_the_discretisation():
    """Default sd: RMS per axis of the angle to the closest of the 32 normals, checked by random sampling."""
    from fusion_plugins.measurement.direction import receiver_normals as _normals
    proc = testing.build("process", "static_orientation", {})
    model = _direction(proc.layout, position=[1.0, 1.0, 1.0])
    d = _unit(np.random.default_rng(0).normal(size=(50000, 3)))
    ang = np.arccos(np.clip((d @ _normals("truncated_icosahedron").T).max(axis=1), -1, 1))
    assert model.sd == pytest.approx(np.sqrt(np.mean(ang ** 2) / 2), rel=0.01)
    assert np.rad2deg(ang.max()) < 23.0 and 9.0 < np.rad2deg(model.sd) < 11.5


def test_direction_bad_input():
    proc = testing.build("process", "static_orientation", {})
    with pytest.raises(ConfigError, match="position"):
        _direction(proc.layout)
    model = _direction(proc.layout, position=[1.0, 1.0, 1.0])
    for vals in (("B1", 1.0, 0.0), ("B1", 1.0, 33.0), ("B1", 1.0, 2.5), ("B9", 1.0, 3.0), ("B1", 1.0)):
        with pytest.raises(MalformedMessage):
            model.observe(Message(1.0, "us", vals))
    with pytest.raises(ConfigError, match="quaternion"):
        _direction(testing.build("process", "firing_clock", {}).layout)


# --------------------------------------------------------------------------- processes
def test_static_orientation_noise_is_a_small_body_rotation():
    """Q = (s^2/4) Xi Xi^T (+ norm term): the covariance of q (x) exp(w/2), w ~ N(0, s^2 I), sampled."""
    proc = testing.build("process", "static_orientation", {"angle_sd_deg": 2.0, "step_s": 0.225, "norm_sd": 1e-9})
    q = Rotation.from_euler("xyz", [20, 40, -70], degrees=True).as_quat(scalar_first=True)
    w = np.random.default_rng(1).normal(0.0, np.deg2rad(2.0), (200000, 3))
    samples = quat.multiply(q, quat.exp(w))
    Q = proc.Q(q, None, 0.225)
    assert np.abs(np.cov(samples.T) - Q).max() < 0.03 * np.abs(Q).max()
    assert np.allclose(proc.Q(q, None, 0.45), 2 * Q)
    assert np.allclose(proc.f(q, None, 1.0), q) and np.allclose(proc.jacobian(q, None, 1.0), np.eye(4))


def test_firing_clock_with_attitude():
    proc = testing.build("process", "firing_clock", {"attitude_sd_deg": 0.57})
    assert [b.name for b in proc.layout.blocks] == ["p", "T", "t", "q"] and proc.layout.n == 9
    x = np.r_[1.0, 1.0, 1.0, 0.225, 3.0, 2.0 * quat.exp(np.array([0.1, 0.2, 0.3]))]
    assert np.isclose(np.linalg.norm(proc.normalize(x)[5:]), 1.0)
    Q = proc.Q(proc.normalize(x), None, 0.225)
    assert np.all(np.linalg.eigvalsh(Q[5:, 5:]) > 0)
    assert testing.check_process_jacobian(proc, x, None, 0.23) < 1e-6


def test_cell_constraint():
    """Zero inside the receiver's cell (exactly where that receiver is the closest), negative outside: the
    signed distance (sine) to the violated bisecting great circle; Jacobian by finite differences outside."""
    from fusion_plugins.measurement.direction import receiver_normals as _normals
    N = _normals("truncated_icosahedron")
    proc = testing.build("process", "static_orientation", {})
    model = _direction(proc.layout, position=[1.2, 0.9, 1.4], cell=True)
    obs = model.observe(Message(1.0, "us", ("B2", 1.0, 14.0)))
    assert obs.z.shape == (4,) and obs.z[3] == 0.0 and obs.R.shape == (4, 4)
    Q = Rotation.random(2000, random_state=5).as_quat(scalar_first=True)
    hc = obs.model.h(Q)[:, 3]
    dirs = obs.model.h(Q)[:, :3]
    closest = np.argmax(dirs @ N.T, axis=1) + 1
    assert np.all((hc == 0.0) == (closest == 14)) and np.all(hc <= 0.0)
    j = int(np.flatnonzero(hc < -0.05)[0])
    assert testing.check_measurement_jacobian(obs.model, Q[j]) < 1e-6
    # clipped residual: a prediction far outside is pulled by at most cell_clip_sigma sd
    r = obs.model.residual(obs.z, obs.model.h(Q[j]))
    assert r[3] == pytest.approx(2.0 * np.deg2rad(1.0))
