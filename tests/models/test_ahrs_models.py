"""The AHRS models (issue 32 item 3) against independent references: ``gravity`` against scipy's Rotation
(f = -C_n^b g_n), its adaptive R and gate; ``gyro_attitude`` against scipy's rotation-vector integration
and its run path against sample-by-sample steps; ``magnetometer_checked``'s intensity and dip checks."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion import testing
from fusion.api import BuildContext, Message, RejectedMessage, StateLayout

AHRS = StateLayout.parse("q:4:quaternion bw:3")
G = 9.80665
FIELD = np.array([21.0, 1.6, 44.0])          # uT, NED (any field: the checks are relative to it)


def gravity(**params):
    cls = testing.registry_class("measurement", "gravity")
    return cls(cls.Params(**params), BuildContext(layout=AHRS, sensor="acc"))


def states(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    q = Rotation.random(n, random_state=seed).as_quat(scalar_first=True)
    return np.column_stack([q * rng.uniform(0.8, 1.2, (n, 1)), rng.normal(0.0, 0.01, (n, 3))])


def test_gravity_h_is_minus_c_nb_g_as_scipy():
    X = states(50)
    C_bn = Rotation.from_quat(X[:, :4], scalar_first=True)          # normalises, as the model divides by |q|^2
    ref = -C_bn.inv().apply([0.0, 0.0, G])
    model = gravity()
    assert np.allclose(model.h(X), ref, atol=1e-12)
    assert np.allclose(np.array([model.h(x) for x in X]), ref, atol=1e-12)
    # a level body at rest reads -g on its down axis (the ins process's and the IMU simulator's sign)
    assert np.allclose(model.h(np.array([1.0, 0, 0, 0, 0, 0, 0])), [0.0, 0.0, -G])


def test_gravity_noise_is_adaptive_and_the_gate_rejects():
    model = gravity(noise_sd=0.03, motion_sd=0.5, motion_tau=0.2, max_deviation=2.0)
    k = 2 * 0.2 / 0.04                                              # equivalent-white factor at 25 Hz
    f_rest = np.array([0.0, 0.0, -G])
    assert np.allclose(model.noise(f_rest, 0.04), np.eye(3) * (0.03 ** 2 + k * 0.5 ** 2))
    f_acc = np.array([0.0, 0.0, -G - 1.0])                          # 1 m/s^2 along gravity
    assert np.allclose(model.noise(f_acc, 0.04), np.eye(3) * (0.03 ** 2 + k * (0.5 ** 2 + 1.0)))
    assert model.observe(Message(0.0, "acc", (0.1, 0.0, -9.8))).R is not None
    with pytest.raises(RejectedMessage, match="max_deviation"):
        model.observe(Message(0.04, "acc", (0.0, 0.0, -G - 2.5)))
    obs = model.observe(Message(0.08, "acc", (0.1, 0.2, -9.7, 0.5, 0.5, 0.5)))   # a whole IMU line
    assert np.allclose(obs.z, [0.1, 0.2, -9.7])


def test_gyro_attitude_matches_scipy_rotation_integration():
    cls = testing.registry_class("process", "gyro_attitude")
    p = cls()
    rng = np.random.default_rng(3)
    x = np.concatenate([Rotation.random(random_state=4).as_quat(scalar_first=True), [0.01, -0.02, 0.005]])
    q_ref = Rotation.from_quat(x[:4], scalar_first=True)
    for _ in range(100):
        u = np.concatenate([rng.normal(0, 1, 3), rng.normal(0, 2.0, 3)])
        x = p.f(x, u, 0.01)
        q_ref = q_ref * Rotation.from_rotvec((u[3:] - x[4:]) * 0.01)    # body-frame increment, bias constant
    assert np.allclose(Rotation.from_quat(x[:4], scalar_first=True).as_matrix(), q_ref.as_matrix(), atol=1e-10)


def test_gyro_attitude_run_path_equals_steps():
    cls = testing.registry_class("process", "gyro_attitude")
    p = cls(cls.Params(angular_accel_sd=5.0))
    rng = np.random.default_rng(5)
    x = states(1, 6)[0]
    us = rng.normal(0, 2.0, (7, 6))
    dts = rng.uniform(0.005, 0.02, 7)
    x1, F, Q = p.linearise_inputs(x, us, dts)
    xs = x.copy()
    for j in range(7):
        xs[:4] /= np.linalg.norm(xs[:4])
        assert np.allclose(F[j], p.jacobian(xs, us[j], dts[j]), atol=1e-12)
        assert np.allclose(Q[j], p.Q(xs, us[j], dts[j]), atol=1e-15)
        xs = p.f(xs, us[j], dts[j])
    xs[:4] /= np.linalg.norm(xs[:4])
    assert np.allclose(x1, xs, atol=1e-12)


def checked(**params):
    cls = testing.registry_class("measurement", "magnetometer_checked")
    return cls(cls.Params(field_ned=tuple(FIELD), **params), BuildContext(layout=AHRS, sensor="mag"))


def test_magnetometer_checked_rejects_intensity_and_dip():
    model = checked(max_intensity_error=0.1, max_dip_error_deg=5.0)
    C = Rotation.from_euler("xyz", [10, -20, 70], degrees=True)      # C_b^n
    m_b = C.inv().apply(FIELD)
    f_b = -C.inv().apply([0.0, 0.0, G])
    model.take_input(0.0, np.concatenate([f_b, np.zeros(3)]))
    assert model.observe(Message(0.0, "mag", tuple(m_b))) is not None          # the clean field passes
    with pytest.raises(RejectedMessage, match="intensity"):
        model.observe(Message(0.1, "mag", tuple(1.15 * m_b)))                  # 15 % stronger
    tilt = Rotation.from_rotvec(np.radians(8.0) * np.array([0.0, 1.0, 0.0]))   # the same intensity, 8 deg off
    with pytest.raises(RejectedMessage, match="dip"):
        model.observe(Message(0.2, "mag", tuple(C.inv().apply(tilt.apply(FIELD)))))
    model.take_input(0.3, np.concatenate([f_b * 1.3, np.zeros(3)]))           # accelerating: dip not judged
    assert model.observe(Message(0.3, "mag", tuple(C.inv().apply(tilt.apply(FIELD))))) is not None
