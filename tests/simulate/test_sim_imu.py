"""IMU simulator: the noise-free IMU integrates back to the truth; errors have the configured statistics."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import parse_log, run_yaml, table
from scipy.spatial.transform import Rotation
from sim_strapdown_ref import strapdown

G = 9.80665


def test_noise_free_imu_integrates_back_to_truth(yaml_3d_turning):
    """Issue 4: an independent strapdown on the noise-free 100 Hz IMU (as written in the log, 6 decimals)
    recovers the truth: position error under 1 cm after 60 s on a turning 3-D trajectory."""
    msgs, _ = parse_log(run_yaml(yaml_3d_turning, noise=False))
    imu, truth = table(msgs["imu"]), table(msgs["truth"])
    assert np.allclose(np.diff(imu[:, 0]), 0.01) and np.array_equal(imu[:, 0], truth[:, 0])
    t_end = 63.0
    k = int(round(t_end * 100))
    p, v, q = strapdown(imu[:, 0], imu[:, 1:4], imu[:, 4:7], truth[0, 1:4], truth[0, 4:7], truth[0, 7:11],
                        G, t_end)
    travelled = np.sum(np.linalg.norm(np.diff(truth[:k, 1:4], axis=0), axis=1))
    assert travelled > 100.0  # it really moved (and turned)
    pos_err = np.linalg.norm(p - truth[k, 1:4])
    assert pos_err < 0.01, pos_err
    assert np.linalg.norm(v - truth[k, 4:7]) < 1e-3
    att_err = (Rotation.from_quat(q, scalar_first=True).inv()
               * Rotation.from_quat(truth[k, 7:11], scalar_first=True)).magnitude()
    assert att_err < 1e-5, att_err


def test_static_imu_reads_minus_gravity_and_zero_rate():
    yaml = """
dim: 3
trajectory: {type: random_walk, start: [0, 0, 0], start_attitude_deg: [0, 0, 0], position_step_sd: 0,
             angle_step_sd_deg: 0}
duration: 2
sensors: {imu: {type: imu, rate_hz: 50}}
"""
    imu = table(parse_log(run_yaml(yaml, noise=False))[0]["imu"])
    assert np.allclose(imu[:, 1:], [0, 0, -G, 0, 0, 0], atol=1e-6)


def test_tilted_static_imu_sees_gravity_in_body_frame():
    yaml = """
dim: 3
trajectory: {type: random_walk, start: [0, 0, 0], start_attitude_deg: [10, -20, 70], position_step_sd: 0,
             angle_step_sd_deg: 0}
duration: 1
sensors: {imu: {type: imu, rate_hz: 10}}
"""
    msgs, _ = parse_log(run_yaml(yaml, noise=False))
    imu, truth = table(msgs["imu"]), table(msgs["truth"])
    C_bn = Rotation.from_quat(truth[0, 7:11], scalar_first=True)
    assert np.allclose(imu[0, 1:4], C_bn.apply([0, 0, -G], inverse=True), atol=2e-6)
    roll, pitch = np.arctan2(-imu[0, 2], -imu[0, 3]), np.arcsin(imu[0, 1] / G)
    assert np.allclose(np.degrees([roll, pitch]), [10, -20], atol=1e-4)


def test_noise_biases_and_scale_factors_have_the_configured_statistics():
    yaml = """
dim: 3
seed: 3
trajectory: {type: random_walk, start: [0, 0, 0], position_step_sd: 0, angle_step_sd_deg: 0}
duration: 100
sensors:
  imu: {type: imu, rate_hz: 100, accel_noise_density: 0.002, gyro_noise_density: 0.0006,
        accel_bias: [0.1, -0.2, 0.3], gyro_bias: [0.01, 0.02, -0.03], accel_scale_sd: 0.01}
"""
    msgs, header = parse_log(run_yaml(yaml))
    imu, truth = table(msgs["imu"]), table(msgs["truth"])
    assert header.fields["truth"][10:] == ("bax", "bay", "baz", "bwx", "bwy", "bwz",
                                            "sax", "say", "saz", "swx", "swy", "swz")
    sd = imu[:, 1:].std(axis=0)
    assert np.allclose(sd[:3], 0.002 * 10, rtol=0.05) and np.allclose(sd[3:], 0.0006 * 10, rtol=0.05)
    assert np.allclose(truth[:, 11:14], [0.1, -0.2, 0.3]) and np.allclose(truth[:, 14:17], [0.01, 0.02, -0.03])
    s = truth[0, 17:20]
    assert np.all(s != 1.0) and np.allclose(s, 1.0, atol=0.05) and np.allclose(truth[0, 20:23], 1.0)
    # measured = s * f + b + noise, f = [0, 0, -g] at rest
    assert np.allclose(imu[:, 1:4].mean(axis=0), s * [0, 0, -G] + [0.1, -0.2, 0.3], atol=5e-4)


def test_bias_random_walk_grows_like_sqrt_time():
    yaml = """
dim: 3
trajectory: {type: random_walk, start: [0, 0, 0], position_step_sd: 0, angle_step_sd_deg: 0}
duration: 25
sensors: {imu: {type: imu, rate_hz: 4, gyro_bias_rw: 1.0e-3, accel_bias_rw: 1.0e-2}}
"""
    ends = []
    for seed in range(60):
        truth = table(parse_log(run_yaml(yaml, seed=seed))[0]["truth"])
        ends.append(truth[-1, 11:17] - truth[0, 11:17])
    ends = np.array(ends)  # 60 seeds x 3 axes: the rms over all of them is good to about 5 %
    assert np.sqrt(np.mean(ends[:, :3] ** 2)) == pytest.approx(1e-2 * 5, rel=0.2)
    assert np.sqrt(np.mean(ends[:, 3:] ** 2)) == pytest.approx(1e-3 * 5, rel=0.2)


def test_scale_factor_random_walk():
    """accel_scale_rw / gyro_scale_rw: the scale factors of the truth lines walk with steps of variance
    rw^2 dt, and the samples are s(t) times the exact ones (paper 002 eq. 13, the ins process's walk)."""
    yaml = """
dim: 3
seed: 5
trajectory: {type: random_walk, start: [0, 0, 0], position_step_sd: 0, angle_step_sd_deg: 2, seed: 1}
duration: 400
sensors:
  imu: {type: imu, rate_hz: 10, accel_noise_density: 0, gyro_noise_density: 0, accel_scale_sd: 0.01,
        gyro_scale_sd: 0.01, accel_scale_rw: 1.0e-3, gyro_scale_rw: 2.0e-3}
"""
    on, _ = parse_log(run_yaml(yaml))
    off, _ = parse_log(run_yaml(yaml, noise=False))
    imu, exact, truth = table(on["imu"]), table(off["imu"]), table(on["truth"])
    assert np.array_equal(imu[:, 0], truth[:, 0])
    s = truth[:, 17:23]                                   # sax say saz swx swy swz at the IMU's times
    steps = np.diff(s, axis=0)
    tol = 5.0 * np.sqrt(2.0 / steps[:, :3].size)
    assert np.var(steps[:, :3]) == pytest.approx(1e-3 ** 2 * 0.1, rel=tol)
    assert np.var(steps[:, 3:]) == pytest.approx(2e-3 ** 2 * 0.1, rel=tol)
    assert np.abs(s[-1] - s[0]).max() > 0.005             # it really walked
    assert np.allclose(imu[:, 1:4], s[:, :3] * exact[:, 1:4], atol=2e-6)
    big = np.abs(exact[:, 4:7]) > 0.05
    assert big.sum() > 1000
    assert np.allclose((imu[:, 4:7] / np.where(big, exact[:, 4:7], 1.0))[big], s[:, 3:][big], atol=1e-4)
