"""Measurements ``gps`` (loosely coupled fix) and ``magnetometer`` (h = C_n^b m_n), paper 002."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion.api import BuildContext, ConfigError, MalformedMessage, Message, StateLayout
from fusion_plugins.filters.jacobian import numerical_jacobian
from fusion_plugins.measurement.gps import Gps, GpsParams
from fusion_plugins.measurement.magnetometer import Magnetometer, MagnetometerParams, earth_field
from fusion_plugins.simulators.magnetometer import earth_field as sim_field

L22 = StateLayout.parse("p:3 v:3 q:4:quaternion ba:3 bw:3 sa:3 sw:3")


def states(rng, n=10):
    X = rng.normal(size=(n, 22))
    X[:, 6:10] = Rotation.random(n, random_state=rng).as_quat(scalar_first=True)
    return X


def gps(**kw):
    return Gps(GpsParams(**kw), BuildContext(layout=L22))


def mag(**kw):
    kw = kw or {"declination_deg": -20.5, "inclination_deg": -36.0, "intensity": 23.5}
    return Magnetometer(MagnetometerParams(**kw), BuildContext(layout=L22))


def test_registered():
    from fusion.registry import default_registry
    r = default_registry()
    assert r.get("measurement", "gps") is Gps and r.get("measurement", "magnetometer") is Magnetometer


def test_gps_h_and_jacobian_with_lever_arm():
    rng = np.random.default_rng(0)
    m = gps(lever_arm=(0.5, -0.2, -1.0))
    X = states(rng)
    Z = m.h(X)
    for x, z in zip(X, Z):
        arm = Rotation.from_quat(x[6:10], scalar_first=True).apply([0.5, -0.2, -1.0])
        np.testing.assert_allclose(z, np.r_[x[0:3] + arm, x[3:5]], atol=1e-12)
        np.testing.assert_allclose(m.jacobian(x), numerical_jacobian(m.h, x), atol=1e-8)
        np.testing.assert_allclose(m.position_from(z, x), x[0:3], atol=1e-12)


def test_gps_velocity_of_an_offset_antenna_turns_with_the_body():
    """With a lever arm the velocity rows are the antenna's, v + C (w x r), w = (u_gyro - bw) / sw from the
    latest IMU sample (a 2 m arm in a 25 deg/s turn is 0.87 m/s). Checked
    against scipy's rotation and a central-difference Jacobian (q, bw, sw included)."""
    from fusion.api import UsesInput

    rng = np.random.default_rng(1)
    arm = np.array([2.0, 0.3, -1.0])
    m = gps(lever_arm=tuple(arm))
    assert isinstance(m, UsesInput) and not isinstance(gps(), UsesInput)   # only with an arm
    assert not isinstance(m.position_only(), UsesInput)
    X = states(rng)
    X[:, 16:22] = 1.0 + 0.05 * rng.normal(size=(len(X), 6))                  # scale factors near 1
    before = m.h(X)
    np.testing.assert_allclose(before[:, 3:5], X[:, 3:5], atol=0)          # no gyro sample yet: no rate term
    u = np.r_[0.1, -0.2, 9.7, 0.05, -0.1, 0.44]                            # accel, gyro (rad/s, FRD)
    m.take_input(1.0, u)
    Z = m.h(X)
    for x, z in zip(X, Z):
        w = (u[3:6] - x[13:16]) / x[19:22]
        rot = Rotation.from_quat(x[6:10], scalar_first=True)
        np.testing.assert_allclose(z[:3], x[0:3] + rot.apply(arm), atol=1e-12)
        np.testing.assert_allclose(z[3:5], x[3:5] + rot.apply(np.cross(w, arm))[:2], atol=1e-12)
        np.testing.assert_allclose(m.jacobian(x), numerical_jacobian(m.h, x), atol=1e-7)


def test_gps_observe_r_scales_with_dop_and_averaging():
    m = gps(horizontal_sd=3.0, vertical_sd=5.0, velocity_sd=0.2)
    obs = m.observe(Message(1.0, "gps", (1, 2, 3, 4, 5, 2.0, np.nan, 8, 1, 1)))
    assert obs.model is m and obs.z.tolist() == [1, 2, 3, 4, 5]
    np.testing.assert_allclose(np.diag(obs.R), [36, 36, 225, 0.16, 0.16])   # HDOP 2; vertical 1.5 HDOP
    obs = m.observe(Message(1.0, "gps", (1, 2, 3, np.nan, np.nan, 1.0, 2.0, 8, 1, 4)))
    assert obs.model.dim == 3 and obs.z.tolist() == [1, 2, 3]               # position only
    np.testing.assert_allclose(np.diag(obs.R), [9 / 4, 9 / 4, 100 / 4])      # VDOP 2, averaged over 4
    assert gps(hdop_scaling=False).observe(Message(1.0, "gps", (1, 2, 3, 4, 5, 3.0, 3.0, 8, 1, 1))).R[0, 0] == 2.5 ** 2
    with pytest.raises(MalformedMessage):
        m.observe(Message(1.0, "gps", (1, 2)))
    with pytest.raises(ConfigError):
        Gps(GpsParams(), BuildContext(layout=StateLayout.parse("p:3")))


def test_field_from_angles_matches_the_simulator_and_the_definition():
    np.testing.assert_allclose(earth_field(-20.5, -36.0, 23.5), sim_field(-20.5, -36.0, 23.5))
    m = earth_field(10.0, 60.0, 50.0)
    assert np.isclose(np.linalg.norm(m), 50.0)
    assert np.isclose(np.degrees(np.arctan2(m[1], m[0])), 10.0)
    assert np.isclose(np.degrees(np.arcsin(m[2] / 50.0)), 60.0)


@pytest.mark.parametrize("direction_only", [False, True])
def test_magnetometer_h_is_scipy_inverse_rotation_and_jacobian_is_exact(direction_only):
    rng = np.random.default_rng(1)
    m = mag(field_ned=(20.0, -5.0, 40.0), direction_only=direction_only)
    ref = np.array([20.0, -5.0, 40.0])
    if direction_only:
        ref = ref / np.linalg.norm(ref)
    X = states(rng)
    X[:, 6:10] *= rng.uniform(0.9, 1.1, (10, 1))             # non-unit q: the direction of q is used
    Z = m.h(X)
    for x, z in zip(X, Z):
        r = Rotation.from_quat(x[6:10], scalar_first=True)
        np.testing.assert_allclose(z, r.inv().apply(ref), atol=1e-12)
        np.testing.assert_allclose(m.jacobian(x), numerical_jacobian(m.h, x), atol=1e-7)


def test_magnetometer_params():
    from pydantic import ValidationError
    with pytest.raises(ValidationError):
        MagnetometerParams(declination_deg=1.0)
    with pytest.raises(ValidationError):
        MagnetometerParams(field_ned=(1, 0, 0), intensity=3.0)
    with pytest.raises(MalformedMessage):
        mag().observe(Message(0.0, "mag", (1.0, 2.0)))


def test_an_alignment_without_magnetometer_samples_leaves_the_heading_unknown():
    """No magnetometer sample in initial.align_s (none, later, or late): started from the config's yaw
    guess at its sd 0.02 rad (a 90 deg error held at 1.1 deg) the filter would diverge. The heading
    sd is that of an unknown heading, roll and pitch keep the accelerometer's levelling sd, and one warning
    says so."""
    from fusion_plugins.measurement.attitude import error_to_quaternion

    from fusion_plugins.measurement.magnetometer import HEADING_UNKNOWN_SD

    m = mag()
    x0 = np.zeros(22)
    x0[6:10] = Rotation.from_euler("xyz", [0.02, -0.01, 0.0]).as_quat(scalar_first=True)   # levelled, yaw 0
    x0[16:22] = 1.0
    P0 = np.eye(22) * 0.02 ** 2
    P0[10:13, 10:13] = np.eye(3) * 0.1 ** 2                    # ba sd 0.1 m/s^2
    x1, P1 = m.align_state(x0, P0, np.r_[0.0, 0.0, -9.8, 0.0, 0.0, 0.0], [], np.eye(3) * 0.04)
    np.testing.assert_array_equal(x1, x0)                      # the levelled attitude, the yaw guess
    G = error_to_quaternion(x0[6:10])
    P_theta = 16.0 * G.T @ P1[6:10, 6:10] @ G                  # G^T G = I / 4
    sd = np.sqrt(np.diag(P_theta))
    assert sd[2] == pytest.approx(HEADING_UNKNOWN_SD, rel=1e-6) and HEADING_UNKNOWN_SD > 1.5
    tilt = np.hypot(0.01, 0.1) / 9.80665                       # align_accel_sd and the ba sd, over g
    np.testing.assert_allclose(sd[:2], tilt, rtol=1e-3)
    assert not np.any(P1[6:10, :6]) and not np.any(P1[6:10, 10:])   # no stale cross-covariances
    (w,) = m.take_events()
    assert w.kind == "warning" and "no magnetometer sample in the alignment" in w.detail and "heading unknown" in w.detail
    assert m.take_events() == []
