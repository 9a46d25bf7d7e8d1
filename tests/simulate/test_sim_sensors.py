"""Sensor simulators: with --noise off every measurement equals its true value; errors as configured."""
from __future__ import annotations

import numpy as np
import pymap3d
import pynmea2
import pytest
from conftest import parse_log, parse_scenario, run_yaml, table
from scipy.spatial.transform import Rotation

from fusion.simulate.trajectory import build_trajectory
from fusion_plugins.simulators.arrival import RECEIVER_NORMALS
from fusion_plugins.simulators.magnetometer import earth_field

BEACONS_3D = """
beacons: {B1: [0, 0, -3], B2: [30, 0, -3], B3: [30, 20, -2], B4: [0, 20, -3]}
"""
TRAJ_3D = """
trajectory:
  type: waypoints
  speed: 2.0
  radius: 3.0
  waypoints: [[3, 3, 0], [25, 3, -0.5], [25, 15, 0], [5, 15, 0]]
"""


def _traj(yaml):
    sc = parse_scenario(yaml)
    return build_trajectory(sc.trajectory, sc.dim, sc.duration)


def test_ranges_are_exact_without_noise_with_lever_arm():
    yaml = "dim: 3\n" + BEACONS_3D + TRAJ_3D + """
sensors:
  uwb: {type: range, rate_hz: 5, noise_sd: 0.3, outlier_prob: 0.5, lever_arm: [0.5, -0.2, -1.0]}
"""
    msgs, header = parse_log(run_yaml(yaml, noise=False))
    tr = _traj(yaml)
    B = {"B1": [0, 0, -3], "B2": [30, 0, -3], "B3": [30, 20, -2], "B4": [0, 20, -3]}
    t = np.array([m.t for m in msgs["uwb"]])
    k = tr.sample(t)
    rx = k.p + k.rotation.apply([0.5, -0.2, -1.0])
    true = np.linalg.norm(rx - np.array([B[m.values[0]] for m in msgs["uwb"]]), axis=1)
    assert np.abs(np.array([m.values[1] for m in msgs["uwb"]]) - true).max() <= 1e-6
    assert [m.values[0] for m in msgs["uwb"][:5]] == ["B1", "B2", "B3", "B4", "B1"]
    assert header.fields["uwb"] == ("beacon", "range")


def test_time_of_flight_ranges_are_stamped_at_arrival():
    yaml = "dim: 3\n" + BEACONS_3D + TRAJ_3D + """
sensors:
  us: {type: range, rate_hz: 2, spacing_s: 0.05, speed_of_sound: 343.0}
"""
    msgs, _ = parse_log(run_yaml(yaml, noise=False))
    t = np.array([m.t for m in msgs["us"]])
    r = np.array([m.values[1] for m in msgs["us"]])
    slot = np.round((t - r / 343.0) / 0.05) * 0.05          # emission times are on the 50 ms grid
    assert np.abs(t - r / 343.0 - slot).max() < 2e-6
    tr = _traj(yaml)
    B = {"B1": [0, 0, -3], "B2": [30, 0, -3], "B3": [30, 20, -2], "B4": [0, 20, -3]}
    true = np.linalg.norm(tr.sample(t).p - np.array([B[m.values[0]] for m in msgs["us"]]), axis=1)
    assert np.abs(r - true).max() < 2e-6


def test_range_errors_outliers_dropouts_and_reach():
    yaml = "dim: 2\nseed: 4\n" + """
beacons: {A: [0, 0], B: [100, 0]}
trajectory: {type: waypoints, speed: 1.0, waypoints: [[10, 0], [10, 60]]}
sensors:
  r: {type: range, rate_hz: 20, noise_sd: 0.05, outlier_prob: 0.1, outlier_min: 1.0, outlier_max: 2.0,
      dropout_prob: {A: 0.5}, max_range: 80}
"""
    msgs, _ = parse_log(run_yaml(yaml))
    tr = _traj(yaml)
    rows = msgs["r"]
    t = np.array([m.t for m in rows])
    p = tr.sample(t).p[:, :2]
    B = {"A": np.array([0.0, 0.0]), "B": np.array([100.0, 0.0])}
    err = np.array([m.values[1] - np.linalg.norm(p[i] - B[m.values[0]]) for i, m in enumerate(rows)])
    out = err > 0.5
    assert 0.07 < out.mean() < 0.13 and np.all((err[out] > 0.8) & (err[out] < 2.2))
    assert np.std(err[~out]) == pytest.approx(0.05, rel=0.1)
    n_a = sum(m.values[0] == "A" for m in rows)
    n_b = sum(m.values[0] == "B" for m in rows)
    assert 0.4 < n_a / (20 * 60) < 0.6          # half of A's ranges dropped
    assert n_b < 0.9 * 20 * 60                  # B is out of reach (> 80 m) at first


def test_planar_ranges_ignore_height():
    yaml = """
dim: 2
beacons: {A: [0, 0], B: [10, 0, -5]}
trajectory: {type: waypoints, waypoints: [[3, 4], [3, 10]]}
sensors: {r: {type: range, rate_hz: 1}}
"""
    msgs, header = parse_log(run_yaml(yaml, noise=False))
    p = _traj(yaml).sample(np.array([m.t for m in msgs["r"]])).p
    B = {"A": [0, 0], "B": [10, 0]}
    for m, pk in zip(msgs["r"], p):
        assert m.values[1] == pytest.approx(np.hypot(*(pk[:2] - B[m.values[0]])), abs=1e-6)
    assert msgs["r"][0].values == ("A", 5.0)
    assert header.fields["truth"] == ("px", "py", "vx", "vy")


def test_arrival_times_and_closest_receiver():
    yaml = """
dim: 3
duration: 30
beacons: {B1: [0, 0, 0], B2: [2.6, 0, 0], B3: [0, 2.6, 0], B4: [0, 0, 2.6]}
trajectory: {type: random_walk, start: [1.5, 1.5, 1.5], start_attitude_deg: [10, 20, 30],
             step_interval: 0.225, position_step_sd: 0.005, angle_step_sd_deg: 0.57, seed: 1}
sensors: {us: {type: arrival_time, period_s: 0.225, first_fire_s: 0.1, speed_of_sound: 340, echo_prob: 0.5,
               period_drift: 0.01, precision: 7}}
"""
    text = run_yaml(yaml, noise=False)
    msgs, header = parse_log(text)
    assert header.fields["us"] == ("beacon", "arrival", "receiver")
    assert "# receiver 32:" in text
    tr = _traj(yaml)
    B = {"B1": [0, 0, 0], "B2": [2.6, 0, 0], "B3": [0, 2.6, 0], "B4": [0, 0, 2.6]}
    order = ["B1", "B2", "B3", "B4"]
    for n, m in enumerate(msgs["us"]):
        beacon, t_a, rec = m.values
        assert beacon == order[n % 4]
        k = tr.sample(np.array([t_a]))
        d = np.array(B[beacon]) - k.p[0]
        t_fire = 0.1 + n * 0.225              # exact period without noise (drift is an error: off)
        assert t_a == pytest.approx(t_fire + np.linalg.norm(d) / 340.0, abs=1e-7)
        u_b = k.rotation.apply(d / np.linalg.norm(d), inverse=True)[0]
        assert int(rec) == int(np.argmax(RECEIVER_NORMALS @ u_b)) + 1
    truth = table(msgs["truth"])
    assert np.allclose(truth[:, 11], 0.225)    # T
    # with noise: echoes arrive late, never early beyond the noise
    noisy = parse_log(run_yaml(yaml))[0]["us"]
    late = np.array([a.values[1] - b.values[1] for a, b in zip(noisy, msgs["us"])])
    assert late.min() > -2e-3 and (late > 0.3 / 340).mean() > 0.3


def test_gps_sentences_decode_to_the_true_position():
    yaml = "dim: 3\n" + TRAJ_3D + """
origin: {lat_deg: 52.0, lon_deg: -1.5, alt_m: 80.0}
start_utc: "2024-03-01T23:59:58"
sensors:
  gps: {type: gps, rate_hz: 1, lever_arm: [0, 0, -1.5], lost_fixes: [5.0], gaps: [[10.0, 4.0]]}
"""
    msgs, _ = parse_log(run_yaml(yaml, noise=False))
    tr = _traj(yaml)
    fixes = {}
    for m in msgs["gps"]:
        s = pynmea2.parse(m.values[0], check=True)   # valid NMEA checksum
        fixes.setdefault(m.t, []).append(s)
    times = sorted(fixes)
    assert 5.0 in times and not any(10.0 <= t < 14.0 for t in times) and 14.0 in times
    for t, (gga, rmc) in fixes.items():
        assert gga.sentence_type == "GGA" and rmc.sentence_type == "RMC"
        if t == 5.0:
            assert gga.gps_qual == 0 and rmc.status == "V" and gga.lat == ""
            continue
        k = tr.sample(np.array([t]))
        ant = k.p[0] + k.rotation.apply([0, 0, -1.5])[0]
        ned = pymap3d.geodetic2ned(gga.latitude, gga.longitude, gga.altitude, 52.0, -1.5, 80.0)
        assert np.abs(np.array(ned) - ant).max() < 0.005
        v_ant = k.v[0] + k.rotation.apply(np.cross(k.w_b[0], [0, 0, -1.5]))[0]
        assert rmc.spd_over_grnd * 1852 / 3600 == pytest.approx(np.hypot(*v_ant[:2]), abs=1e-3)
    assert fixes[0.0][0].timestamp.strftime("%H%M%S") == "235958"
    assert fixes[3.0][1].datestamp.isoformat() == "2024-03-02"


def test_gps_without_origin_is_a_config_error():
    from fusion.api import ConfigError
    with pytest.raises(ConfigError, match="origin"):
        run_yaml("dim: 3\n" + TRAJ_3D + "sensors: {gps: {type: gps}}\n")


def test_magnetometer_is_the_rotated_earth_field():
    yaml = "dim: 3\n" + TRAJ_3D + """
sensors:
  mag: {type: magnetometer, rate_hz: 5, declination_deg: -20, inclination_deg: -36, intensity: 23.5,
        hard_iron: [3, 0, 0], disturbances: [[5, 2, [10, 0, 0]]]}
"""
    msgs, header = parse_log(run_yaml(yaml, noise=False))
    tr = _traj(yaml)
    mag = table(msgs["mag"])
    k = tr.sample(mag[:, 0])
    m_n = earth_field(-20, -36, 23.5)
    assert np.abs(mag[:, 1:] - k.rotation.apply(m_n, inverse=True)).max() < 1e-6
    assert np.allclose(np.linalg.norm(mag[:, 1:], axis=1), 23.5, atol=1e-5)
    assert m_n[2] < 0 and np.degrees(np.arctan2(m_n[1], m_n[0])) == pytest.approx(-20)
    noisy = table(parse_log(run_yaml(yaml))[0]["mag"])
    assert np.abs(noisy[:, 1:] - mag[:, 1:]).mean() > 0.5   # hard iron and the disturbance show


def test_position_fixes():
    yaml = "dim: 2\n" + """
trajectory: {type: waypoints, waypoints: [[0, 0], [10, 0]]}
sensors: {pos: {type: position, rate_hz: 2, noise_sd: [0.1, 0.2]}}
"""
    exact, header = parse_log(run_yaml(yaml, noise=False))
    assert header.fields["pos"] == ("x", "y")
    truth = {m.t: m.values[:2] for m in exact["truth"]}
    for m in exact["pos"]:
        assert m.values == pytest.approx(truth[m.t], abs=1e-6)


def test_attitude_truth_matches_rotation():
    yaml = "dim: 3\n" + TRAJ_3D + "sensors: {imu: {type: imu, rate_hz: 10}}\n"
    truth = table(parse_log(run_yaml(yaml, noise=False))[0]["truth"])
    k = _traj(yaml).sample(truth[:, 0])
    R = Rotation.from_quat(truth[:, 7:11], scalar_first=True)
    assert (R.inv() * k.rotation).magnitude().max() < 3e-6
