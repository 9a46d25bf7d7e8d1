"""Solvers hand their measurement models a typed fusion.api.Fix, not a float array: the geometric TDOA
fix to ``position``, the TRIAD and geometric attitude fixes to ``attitude``, the paper 003 initial state fix
to ``arrival_time`` and ``direction``; each model reads the fields (value, covariance, attitude and its
rotation-vector covariance) and refuses a fix it cannot use."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion import quaternion as quat
from fusion import testing
from fusion.api import BuildContext, Fix, MalformedMessage, Message
from fusion_plugins.solvers.initial_fix import initial_fix, observe_initial, quaternion_covariance

LAB = {"B1": [0, 0, 0], "B2": [2.6, 0, 0], "B3": [0, 2.6, 0], "B4": [0, 0, 2.6]}
BEACONS = {k: np.array(v, float) for k, v in LAB.items()}
C, T = 340.0, 0.225


def _cycle(r, rot=None):
    """One cycle of exact arrivals from r (and, with an attitude, the closest receiver of each)."""
    from fusion_plugins.measurement.direction import receiver_normals

    N = receiver_normals("truncated_icosahedron")
    out = []
    for k, (name, b) in enumerate(BEACONS.items()):
        a = 0.1 + T * k + np.linalg.norm(r - b) / C
        rec = 11 if rot is None else int(np.argmax(N @ rot.inv().apply((b - r) / np.linalg.norm(b - r)))) + 1
        out.append(Message(a, "us", (name, a, float(rec)), 7 + k))
    return out


def test_tdoa_fix_is_observed_by_position_with_its_covariance():
    r = np.array([0.59, 1.14, 0.9])
    s = testing.build("solver", "tdoa_geometric", {}, BuildContext(beacons=BEACONS, sensor="us"))
    (fix,) = [f for m in _cycle(r) for f in s.feed(m)]
    assert isinstance(fix, Fix) and fix.line == 10 and fix.sensor == "us" and fix.t == _cycle(r)[-1].t
    proc = testing.build("process", "pv", {"dims": 3})
    model = testing.build("measurement", "position", {}, BuildContext(layout=proc.layout))
    obs = model.observe(fix)
    np.testing.assert_allclose(obs.z, r, atol=1e-8)
    assert np.array_equal(obs.R, fix.cov) and obs.t == fix.t and obs.model is model


def test_triad_fix_is_observed_by_attitude_as_the_recorded_message_would_be():
    """The typed fix and a recording's ``qw qx qy qz`` + upper-triangle message give the same observation."""
    from fusion_plugins.solvers.triad import TriadParams, TriadSolver

    layout = testing.build("process", "ins", {"states": 16}).layout
    M_N = np.array([20.0, 1.0, 45.0])
    s = TriadSolver(TriadParams(field_ned=tuple(M_N), accel_disturbance_sd=0.0), BuildContext(layout=layout))
    Cbn = Rotation.from_euler("ZYX", [1.0, 0.1, -0.2]).as_matrix()
    s.take_input(0.0, np.r_[Cbn.T @ np.array([0.0, 0.0, -9.80665]), 0.0, 0.0, 0.0])
    (fix,) = s.feed(Message(1.0, "mag", tuple(Cbn.T @ M_N), 3))
    model = testing.build("measurement", "attitude", {}, BuildContext(layout=layout))
    typed = model.observe(fix)
    P = fix.attitude_cov
    recorded = model.observe(Message(1.0, "mag", tuple(fix.attitude) + tuple(P[np.triu_indices(3)])))
    assert np.array_equal(typed.R, recorded.R) and np.array_equal(typed.model.q_m, recorded.model.q_m)
    assert quat.angle_between(typed.model.q_m, quat.from_matrix(Cbn)) < 1e-9
    with pytest.raises(MalformedMessage, match="no attitude"):
        model.observe(Fix(1.0, np.zeros(3)))


def test_geometric_attitude_fix_is_observed_by_attitude():
    """orientation_geometric's fix: the attitude with attitude_sd_deg per axis, which the attitude model
    observes (h is zero at the fix's own attitude)."""
    r, rot = np.array([1.2, 1.1, 1.4]), Rotation.from_euler("xyz", [10, -20, 30], degrees=True)
    s = testing.build("solver", "orientation_geometric", {"attitude_sd_deg": 5.0, "receivers": "truncated_icosahedron"},
                      BuildContext(beacons=BEACONS, sensor="us"))
    (fix,) = [f for m in _cycle(r, rot) for f in s.feed(m)]
    np.testing.assert_allclose(fix.attitude_cov, np.deg2rad(5.0) ** 2 * np.eye(3), rtol=1e-12)
    layout = testing.build("process", "static_orientation", {}).layout
    obs = testing.build("measurement", "attitude", {}, BuildContext(layout=layout)).observe(fix)
    assert np.array_equal(obs.R, fix.attitude_cov)
    np.testing.assert_allclose(obs.model.h(fix.attitude), np.zeros(3), atol=1e-12)


def test_direction_refuses_an_initial_fix_without_arrival_times():
    proc = testing.build("process", "firing_clock", {"attitude_sd_deg": 1.0})
    ctx = BuildContext(layout=proc.layout, beacons=BEACONS, sensor="us")
    fix = initial_fix(np.array([1.0, 1.0, 1.0]), np.eye(3) * 1e-4, BEACONS["B4"], 1.0, C, 2e-4,
                      np.array([1.0, 0, 0, 0]), 0.2)
    with pytest.raises(MalformedMessage, match="arrival: true"):
        testing.build("measurement", "direction", {"receivers": "truncated_icosahedron"}, ctx).observe(fix)
    obs = testing.build("measurement", "direction", {"arrival": True, "receivers": "truncated_icosahedron"}, ctx).observe(fix)
    assert obs.z.shape == (8,) and obs.R.shape == (8, 8) and np.all(np.linalg.eigvalsh(obs.R) > 0)
    bad = Fix(fix.t, fix.value, fix.cov, attitude=fix.attitude, attitude_cov=-np.eye(3))
    with pytest.raises(MalformedMessage, match="positive diagonal"):
        observe_initial(bad, ctx)


@pytest.mark.parametrize("seed", range(3))
def test_quaternion_covariance_matches_sampled_rotations(seed):
    """The quaternion block from a rotation-vector covariance, against the scatter of
    q_fix = exp(d theta / 2) (x) q for d theta ~ N(0, C), isotropic and not (200 000 samples)."""
    rng = np.random.default_rng(seed)
    q = quat.normalize(rng.normal(size=4))
    A = rng.normal(size=(3, 3)) * 0.02
    for cov in (A @ A.T + 1e-5 * np.eye(3), 4e-4 * np.eye(3)):
        d = rng.multivariate_normal(np.zeros(3), cov, 200_000)
        qs = quat.multiply(quat.exp(d), q)
        qs *= np.sign(qs @ q)[:, None]
        sample = np.cov(qs.T)
        model = quaternion_covariance(q, cov, norm_var=0.0)
        assert np.abs(sample - model).max() < 0.02 * np.abs(model).max()
