"""The ``omni`` process against an independent transcription of robot_localization's own prediction
(ekf.cpp: ``transferFunction_``, ``transferFunctionJacobian_`` element by element, ``P = J P J^T + Q dt``), and
the pose / twist / imu models' per-axis selection, modes and covariances."""
from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.api import BuildContext, Message
from fusion.registry import default_registry


def _rl_predict(x, P, Qc, dt):
    """robot_localization Ekf::predict, transcribed from its C++ (state order x y z r p y vx vy vz vr vp vy ax ay az)."""
    r, p, y = x[3], x[4], x[5]
    xv, yv, zv, rv, pv, yv_ = x[6], x[7], x[8], x[9], x[10], x[11]
    xa, ya, za = x[12], x[13], x[14]
    sp, cp = math.sin(p), math.cos(p)
    cpi = 1.0 / cp
    tp = sp * cpi
    sr, cr = math.sin(r), math.cos(r)
    sy, cy = math.sin(y), math.cos(y)
    T = np.eye(15)
    T[0, 6] = cy * cp * dt
    T[0, 7] = (cy * sp * sr - sy * cr) * dt
    T[0, 8] = (cy * sp * cr + sy * sr) * dt
    T[0, 12] = 0.5 * T[0, 6] * dt
    T[0, 13] = 0.5 * T[0, 7] * dt
    T[0, 14] = 0.5 * T[0, 8] * dt
    T[1, 6] = sy * cp * dt
    T[1, 7] = (sy * sp * sr + cy * cr) * dt
    T[1, 8] = (sy * sp * cr - cy * sr) * dt
    T[1, 12] = 0.5 * T[1, 6] * dt
    T[1, 13] = 0.5 * T[1, 7] * dt
    T[1, 14] = 0.5 * T[1, 8] * dt
    T[2, 6] = -sp * dt
    T[2, 7] = cp * sr * dt
    T[2, 8] = cp * cr * dt
    T[2, 12] = 0.5 * T[2, 6] * dt
    T[2, 13] = 0.5 * T[2, 7] * dt
    T[2, 14] = 0.5 * T[2, 8] * dt
    T[3, 9] = dt
    T[3, 10] = sr * tp * dt
    T[3, 11] = cr * tp * dt
    T[4, 10] = cr * dt
    T[4, 11] = -sr * dt
    T[5, 10] = sr * cpi * dt
    T[5, 11] = cr * cpi * dt
    T[6, 12] = T[7, 13] = T[8, 14] = dt
    h = 0.5 * dt * dt
    J = T.copy()
    yc, zc = cy * sp * cr + sy * sr, -cy * sp * sr + sy * cr
    J[0, 3] = (yc * yv + zc * zv) * dt + (yc * ya + zc * za) * h
    J[3, 3] = 1.0 + (cr * tp * pv - sr * tp * yv_) * dt
    xc, yc, zc = -cy * sp, cy * cp * sr, cy * cp * cr
    J[0, 4] = (xc * xv + yc * yv + zc * zv) * dt + (xc * xa + yc * ya + zc * za) * h
    J[3, 4] = (cpi * cpi * sr * pv + cpi * cpi * cr * yv_) * dt
    xc, yc, zc = -sy * cp, -sy * sp * sr - cy * cr, -sy * sp * cr + cy * sr
    J[0, 5] = (xc * xv + yc * yv + zc * zv) * dt + (xc * xa + yc * ya + zc * za) * h
    yc, zc = sy * sp * cr - cy * sr, -sy * sp * sr - cy * cr
    J[1, 3] = (yc * yv + zc * zv) * dt + (yc * ya + zc * za) * h
    J[4, 3] = (-sr * pv - cr * yv_) * dt                 # dFP_dR
    xc, yc, zc = -sy * sp, sy * cp * sr, sy * cp * cr
    J[1, 4] = (xc * xv + yc * yv + zc * zv) * dt + (xc * xa + yc * ya + zc * za) * h
    xc, yc, zc = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
    J[1, 5] = (xc * xv + yc * yv + zc * zv) * dt + (xc * xa + yc * ya + zc * za) * h
    yc, zc = cp * cr, -cp * sr
    J[2, 3] = (yc * yv + zc * zv) * dt + (yc * ya + zc * za) * h
    J[5, 3] = (cr * cpi * pv - sr * cpi * yv_) * dt
    xc, yc, zc = -cp, -sp * sr, -sp * cr
    J[2, 4] = (xc * xv + yc * yv + zc * zv) * dt + (xc * xa + yc * ya + zc * za) * h
    J[5, 4] = (sr * tp * cpi * pv + cr * tp * cpi * yv_) * dt
    x1 = T @ x
    P1 = J @ P @ J.T + Qc * dt
    return x1, P1


def _omni(**params):
    reg = default_registry()
    cls = reg.get("process", "omni")
    return cls(cls.Params(**params))


@pytest.mark.parametrize("seed", range(20))
def test_prediction_matches_robot_localization(seed):
    rng = np.random.default_rng(seed)
    x = rng.normal(0, 1, 15)
    x[4] = rng.uniform(-1.2, 1.2)            # pitch away from +-90 deg, where robot_localization's E is singular
    A = rng.normal(0, 1, (15, 15))
    P = A @ A.T + np.eye(15)
    dt = rng.uniform(0.001, 0.2)
    Qc = np.diag(rng.uniform(0.001, 0.1, 15))
    proc = _omni(process_noise_covariance=np.diag(Qc).tolist())
    x_rl, P_rl = _rl_predict(x, P, Qc, dt)
    # same equations, different arithmetic order: agreement to rounding (1e-12 relative of values of order 1-10)
    np.testing.assert_allclose(proc.f(x, None, dt), x_rl, rtol=1e-12, atol=1e-12)
    F = proc.jacobian(x, None, dt)
    np.testing.assert_allclose(F @ P @ F.T + proc.Q(x, None, dt), P_rl, rtol=1e-10, atol=1e-10)


def _rl_transfer(x, dt):
    """robot_localization's transferFunction_ x (the state-dependent T of _rl_predict applied to x)."""
    return _rl_predict(x, np.eye(15), np.zeros((15, 15)), dt)[0]


def _rl_ukf_predict(x, P, Qc, dt, alpha, kappa, beta):
    """robot_localization Ukf::predict: sigma points from chol((n + lambda) P), each through the transfer
    function, weighted mean and covariance plus Q dt."""
    n = 15
    lam = alpha * alpha * (n + kappa) - n
    wm = np.full(2 * n + 1, 1.0 / (2 * (n + lam)))
    wc = wm.copy()
    wm[0] = lam / (n + lam)
    wc[0] = wm[0] + (1 - alpha * alpha + beta)
    L = np.linalg.cholesky((n + lam) * P)
    pts = [x] + [x + L[:, i] for i in range(n)] + [x - L[:, i] for i in range(n)]
    Y = np.array([_rl_transfer(p, dt) for p in pts])
    m = wm @ Y
    D = Y - m
    return m, (wc[:, None] * D).T @ D + Qc * dt


@pytest.mark.parametrize("name", ["ekf", "ukf"])
def test_project_filters_predict_as_robot_localization(name):
    """The project's ekf and ukf predict as robot_localization's Ekf and Ukf (alpha 0.5: at its default 1e-3
    the zeroth weight is ~ -1e6 and agreement holds to ~1e-7 relative only, DESIGN.md)."""
    rng = np.random.default_rng(7)
    x = rng.normal(0, 0.5, 15)
    P = np.diag(rng.uniform(0.01, 0.05, 15))
    proc = _omni()
    reg = default_registry()
    flt = reg.get("filter", name)
    Qc = np.diag(proc.params.process_noise_covariance)
    dt = 0.05
    if name == "ekf":
        f = flt(flt.Params())
        x_rl, P_rl = _rl_predict(x, P, Qc, dt)
    else:
        f = flt(flt.Params(alpha=0.5, beta=2.0, kappa=0.0, linear_prediction="never"))
        x_rl, P_rl = _rl_ukf_predict(x, P, Qc, dt, 0.5, 0.0, 2.0)
    b = f.predict(f.initial_belief(0.0, x, P), proc, None, dt)
    # the same arithmetic up to its order: rounding of values of order 1
    np.testing.assert_allclose(b.x, x_rl, atol=1e-12)
    np.testing.assert_allclose(b.cov, P_rl, atol=1e-12)


def test_two_d_mode_holds_the_planar_states():
    proc = _omni(two_d_mode=True)
    x = np.arange(15, dtype=float) * 0.1
    x1 = proc.f(x, None, 0.1)
    assert np.all(x1[[2, 3, 4, 8, 9, 10, 14]] == 0.0)
    Q = proc.Q(x, None, 0.1)
    assert Q[2, 2] == 1e-6 and Q[2, 0] == 0.0


def _model(kind, **params):
    from fusion_plugins.process.omni import layout

    reg = default_registry()
    cls = reg.get("measurement", kind)
    return cls(cls.Params(**params), BuildContext(layout=layout()))


def _pose_msg(t, p, q, cov6):
    from fusion.importers.rosbag_frames import upper

    return Message(t, "pose", tuple([*p, *q, *upper(cov6)]))


def test_pose_selection_and_message_covariance_with_floor():
    m = _model("pose", select=[True, True, False, False, False, True] + [False] * 9)
    yaw = 0.4
    cov = np.diag([0.04, 0.09, 1.0, 0.0, 0.0, 0.0])
    obs = m.observe(_pose_msg(1.0, [1.0, 2.0, 3.0], [math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)], cov))
    np.testing.assert_allclose(obs.z, [1.0, 2.0, yaw], atol=1e-12)
    np.testing.assert_allclose(np.diag(obs.R), [0.04, 0.09, 1e-6])      # the zero yaw variance floored
    x = np.zeros(15)
    x[5] = yaw + 2 * np.pi - 0.01
    np.testing.assert_allclose(obs.model.residual(obs.z, obs.model.h(x)), [1.0, 2.0, 0.01], atol=1e-12)


def test_pose_relative_and_differential():
    rel = _model("pose", select=["x", "y", "yaw"], relative=True)
    dif = _model("pose", select=["x", "y", "yaw"], differential=True)
    cov = np.eye(6) * 0.01
    y0, y1 = 0.5, 0.7
    m0 = _pose_msg(0.0, [10.0, 5.0, 0.0], [math.cos(y0 / 2), 0, 0, math.sin(y0 / 2)], cov)
    m1 = _pose_msg(0.5, [10.0 + math.cos(y0), 5.0 + math.sin(y0), 0.0], [math.cos(y1 / 2), 0, 0, math.sin(y1 / 2)], cov)
    np.testing.assert_allclose(rel.observe(m0).z, [0.0, 0.0, 0.0], atol=1e-12)
    # 1 m straight ahead of the first pose, turned 0.2 rad: relative (1, 0, 0.2)
    np.testing.assert_allclose(rel.observe(m1).z, [1.0, 0.0, 0.2], atol=1e-12)
    assert dif.observe(m0) is None                                       # no earlier pose: no update
    o = dif.observe(m1)
    np.testing.assert_allclose(o.z, [2.0, 0.0, 0.4], atol=1e-12)         # vx vy vyaw over 0.5 s
    assert list(o.model.idx) == [6, 7, 11]
    np.testing.assert_allclose(np.diag(o.R), [0.08, 0.08, 0.08])         # (0.01 + 0.01) / 0.5^2


def test_imu_gravity_removal_mount_and_missing_parts():
    from fusion.importers.rosbag_frames import upper

    m = _model("imu", select=["roll", "pitch", "yaw", "vyaw", "ax", "ay", "az"], remove_gravitational_acceleration=True)
    roll = 0.3   # tilted about x: at rest the FRD specific force is -g along body z rotated by the roll
    C = np.array([[1, 0, 0], [0, math.cos(roll), -math.sin(roll)], [0, math.sin(roll), math.cos(roll)]])
    f = C.T @ np.array([0.0, 0.0, -9.80665])
    c3 = upper(np.eye(3) * 0.01)
    msg = Message(0.0, "imu", tuple([math.cos(roll / 2), math.sin(roll / 2), 0, 0, 0, 0, 0.1, *f, *c3, *c3, *c3]))
    o = m.observe(msg)
    np.testing.assert_allclose(o.z, [roll, 0, 0, 0.1, 0, 0, 0], atol=1e-12)
    # no orientation (ROS: covariance -1): attitude left out, and gravity cannot be removed
    m2 = _model("imu", select=["yaw", "vyaw"])
    o2 = m2.observe(Message(0.0, "imu", tuple([1, 0, 0, 0, 0, 0, 0.1, 0, 0, -9.8, -1, 0, 0, 0, 0, 0, *c3, *c3])))
    assert list(o2.model.idx) == [11]
    # a sensor turned 90 deg about z (its x is the body's y): its z rate is the body's z rate, x rate -> y
    m3 = _model("imu", select=["vroll", "vpitch"], mount_rotation=(math.sqrt(0.5), 0, 0, math.sqrt(0.5)))
    o3 = m3.observe(Message(0.0, "imu", tuple([1, 0, 0, 0, 0.2, 0, 0, 0, 0, -9.8, *c3, *c3, *c3])))
    np.testing.assert_allclose(o3.z, [0.0, 0.2], atol=1e-12)


def test_twist_lever_arm_and_odometry_twist():
    from fusion.importers.rosbag_frames import upper

    m = _model("twist", select=["vx", "vy", "vyaw"], lever_arm=(0.0, 0.5, 0.0))
    # the body turns at 1 rad/s about z (FRD down): a sensor 0.5 m right moves at (-0.5, 0, 0) without forward speed
    msg = Message(0.0, "twist", tuple([-0.5, 0, 0, 0, 0, 1.0, *upper(np.eye(6) * 0.01)]))
    np.testing.assert_allclose(m.observe(msg).z, [0.0, 0.0, 1.0], atol=1e-12)
    odo = _model("pose", select=["vx", "vyaw"])
    v = [0, 0, 0, 1, 0, 0, 0, *upper(np.eye(6)), 2.0, 0, 0, 0, 0, 0.3, *upper(np.eye(6) * 0.04)]
    o = odo.observe(Message(0.0, "odom", tuple(v)))
    np.testing.assert_allclose(o.z, [2.0, 0.3])
    np.testing.assert_allclose(np.diag(o.R), [0.04, 0.04])
