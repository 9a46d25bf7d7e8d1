"""``fusion import-config``: robot_localization parameter files (ROS 1 and ROS 2 layouts) into omni configs, the
frame change of every axis flag and matrix, what is not translated, --tf mounts, and the whole path of
docs/ros.md: a bag -> fusion import -> import-config -> fusion run (ekf and ukf) against the reference topic."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

from bagmaker import write_bag
from ros_helpers import ROOT, fusion

EKF = ROOT / "docs" / "examples" / "ros" / "ekf.yaml"


def _ros1(tmp_path):
    params = yaml.safe_load(EKF.read_text())["ekf_filter_node"]["ros__parameters"]
    p = tmp_path / "ekf_ros1.yaml"
    p.write_text(yaml.safe_dump({"ekf_se": params}))
    return p


def _translate(tmp_path, params, *extra, name="out.yaml"):
    out = tmp_path / name
    assert fusion("import-config", params, "-o", out, "--name", "t", *extra) == 0
    return yaml.safe_load(out.read_text()), out


def test_ros1_and_ros2_layouts_give_the_same_config(tmp_path):
    a, _ = _translate(tmp_path, EKF, name="a.yaml")
    b, _ = _translate(tmp_path, _ros1(tmp_path), name="b.yaml")
    a.pop("description"), b.pop("description")
    assert a == b
    assert a["process"] == {"type": "omni", "two_d_mode": True}
    assert a["sensors"]["imu_data"]["model"]["select"] == ["yaw", "vyaw", "ax", "ay"]


def test_axes_and_matrices_change_frame(tmp_path):
    q = [float(i + 1) / 100 for i in range(15)]
    P = np.diag(np.arange(1.0, 16.0))
    P[0, 1] = P[1, 0] = 0.5                  # ENU x-y correlation: stays (both axes keep their sign)
    P[0, 2] = P[2, 0] = 0.25                 # ENU x-z: NED y and z = -up: the sign flips
    params = {"odom0": "/o", "odom0_config": [True] + [False] * 5 + [False, True] + [False] * 7,
              "process_noise_covariance": q, "initial_estimate_covariance": P.ravel().tolist(),
              "initial_state": [1.0, 2.0, 3.0, 0.1, 0.2, 0.3] + [0.0] * 9}
    f = tmp_path / "p.yaml"
    f.write_text(yaml.safe_dump(params))
    cfg, _ = _translate(tmp_path, f)
    # ENU x (east) is NED y; a body y (left) flag is the FRD y (right) flag
    assert cfg["sensors"]["o"]["model"]["select"] == ["y", "vy"]
    qn = cfg["process"]["process_noise_covariance"]
    assert qn[:3] == [q[1], q[0], q[2]] and qn[3:] == q[3:]
    m = cfg["initial"]["mean"]
    assert m["p"] == [2.0, 1.0, -3.0] and m["roll"] == 0.1 and m["pitch"] == -0.2
    assert m["yaw"] == pytest.approx(math.pi / 2 - 0.3)
    Pn = np.asarray(cfg["initial"]["P"])
    assert Pn[0, 0] == 2.0 and Pn[1, 1] == 1.0 and Pn[0, 1] == 0.5 and Pn[1, 2] == -0.25


def test_what_is_not_translated_is_said(tmp_path, capsys):
    cfg, out = _translate(tmp_path, EKF)
    err = capsys.readouterr().err
    for key in ("use_control", "sensor_timeout", "odom0_queue_size", "process_noise_covariance"):
        assert f"not translated: {key}" in err
        assert f"#   {key}" in out.read_text()


def test_tf_mounts_the_imu(tmp_path):
    rec = tmp_path / "r.log"
    bag = tmp_path / "r.bag"
    write_bag(bag, "ros1", duration=1.0)
    assert fusion("import", bag, "-o", rec) == 0
    roll, yaw = -math.pi / 2, math.pi / 2
    cfg, _ = _translate(tmp_path, EKF, "--recording", rec, "--tf", "base_link", "imu_link", "0", "-0.3", "0.52",
                        str(roll), "0", str(yaw))
    q = cfg["sensors"]["imu_data"]["model"]["mount_rotation"]
    from scipy.spatial.transform import Rotation

    C_flu = Rotation.from_euler("ZYX", [yaw, 0.0, roll]).as_matrix()
    D = np.diag([1.0, -1.0, -1.0])
    C = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
    np.testing.assert_allclose(C, D @ C_flu @ D, atol=1e-9)


def test_a_file_without_robot_localization_parameters_is_one_error(tmp_path, capsys):
    f = tmp_path / "x.yaml"
    f.write_text("foo: 1\n")
    assert fusion("import-config", f, "-o", tmp_path / "o.yaml") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no robot_localization parameters" in err[0]


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    d = tmp_path_factory.mktemp("robot")
    write_bag(d / "robot.bag", "ros1", duration=30.0)
    (d / "map.yaml").write_text("reference: {topic: /odometry/filtered}\n")
    assert fusion("import", d / "robot.bag", "--map", d / "map.yaml", "-o", d / "robot.log") == 0
    for flt in ("ekf", "ukf"):   # the ukf with robot_localization's own defaults (alpha 1e-3, kappa 0, beta 2)
        assert fusion("import-config", EKF, "--recording", d / "robot.log", "-o", d / f"{flt}.yaml", "--filter", flt) == 0
    return d


@pytest.mark.slow
@pytest.mark.parametrize("flt", ["ekf", "ukf"])
def test_translated_config_runs_and_agrees_with_the_reference(robot, flt):
    out = robot / f"{flt}.json"
    assert fusion("run", robot / f"{flt}.yaml", "--summary-json", out, "--quiet", "--no-progress") == 0
    agree = json.loads(out.read_text())["agreement"]
    # The GPS (0.5 m a coordinate) sets the position; its first fix is the origin, itself 0.5 m off per axis
    # (99.99% of the offsets' norms are below 2.2 m), the filter's own error adds ~0.3 m: 2.5 m bounds both.
    assert agree["position_rmse_m"] < 2.5
    # yaw: the IMU's 0.02 rad at 50 Hz; speed: the wheels' 0.05 m/s at 20 Hz (a quarter of either, and some
    # slack for the turns' lag)
    assert agree["element_rmse"]["yaw"] < 0.02
    assert agree["element_rmse"]["vbx"] < 0.05


HUSKY_LAUNCH = """<launch>
  <param name="/use_sim_time" value="true" />
  <node pkg="tf2_ros" type="static_transform_publisher" name="bl_imu"
        args="0 -0.3 0.52 -1.570796327 0 1.570796327 base_link imu_link" />
  <node pkg="rosbag" type="play" name="rosbagplay" args="$(find robot_localization)/test/test1.bag --clock -d 5" />
  <node name="test_ekf" pkg="robot_localization" type="ekf_localization_node" clear_params="true">
    <param name="frequency" value="30"/>
    <param name="sensor_timeout" value="0.1"/>
    <param name="two_d_mode" value="true"/>
    <param name="odom0" value="/wheel/odometry"/>
    <param name="imu0" value="/imu/data"/>
    <rosparam param="odom0_config">[false, false, false, false, false, false, true, true, false,
                                    false, false, true, false, false, false]</rosparam>
    <rosparam param="imu0_config">[false, false, false, false, false, true, false, false, false,
                                   false, false, true, true, true, false]</rosparam>
    <param name="imu0_remove_gravitational_acceleration" value="true"/>
    <rosparam param="initial_estimate_covariance">[1e-9, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
      0, 1e-9, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,  0, 0, 1e-9, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
      0, 0, 0, 1e-9, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,  0, 0, 0, 0, 1e-9, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
      0, 0, 0, 0, 0, 4.0, 0, 0, 0, 0, 0, 0, 0, 0, 0,  0, 0, 0, 0, 0, 0, 1e-2, 0, 0, 0, 0, 0, 0, 0, 0,
      0, 0, 0, 0, 0, 0, 0, 1e-2, 0, 0, 0, 0, 0, 0, 0,  0, 0, 0, 0, 0, 0, 0, 0, 1e-9, 0, 0, 0, 0, 0, 0,
      0, 0, 0, 0, 0, 0, 0, 0, 0, 1e-9, 0, 0, 0, 0, 0,  0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1e-9, 0, 0, 0, 0,
      0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1e-2, 0, 0, 0,  0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1e-2, 0, 0,
      0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1e-2, 0,  0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1e-9]</rosparam>
  </node>
  <test test-name="bag_pose" pkg="robot_localization" type="test_ekf_localization_node_bag1">
    <param name="final_x" value="{x}"/>
    <param name="final_y" value="{y}"/>
    <param name="final_z" value="0.0"/>
    <param name="tolerance" value="1.0"/>
  </test>
</launch>
"""


@pytest.mark.slow
def test_ros1_launch_with_a_mounted_imu_runs_on_the_bag(tmp_path, capsys):
    """robot_localization's bag-test layout: a launch file with the Husky's IMU mount (x y z yaw pitch roll:
    yaw -90 deg, roll +90 deg), run on the bag directly; the bag's IMU data is in that rotated frame, and its
    /tf_static has it too, so only a right mount gives the right heading."""
    s = math.sqrt(0.5)
    mount = (0.5, 0.5, -0.5, -0.5)        # Rz(-90 deg) Rx(+90 deg), [w x y z]
    from bagmaker import Spec, truth

    write_bag(tmp_path / "husky.bag", "ros1", Spec(imu_mount=mount, imu_arm=(0.0, -0.3, 0.52)), duration=20.0)
    tr = truth(20.0)
    launch = tmp_path / "bag1.test"
    launch.write_text(HUSKY_LAUNCH.format(x=tr.x[-1], y=tr.y[-1]))
    out = tmp_path / "bag1.yaml"
    assert fusion("import-config", launch, "--recording", tmp_path / "husky.bag", "-o", out) == 0
    err = capsys.readouterr().err
    assert "expects the final position" in err
    cfg = yaml.safe_load(out.read_text())
    q = cfg["sensors"]["imu_data"]["model"]["mount_rotation"]
    from scipy.spatial.transform import Rotation

    D = np.diag([1.0, -1.0, -1.0])
    C = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
    C_flu = Rotation.from_quat([mount[1], mount[2], mount[3], mount[0]]).as_matrix()
    np.testing.assert_allclose(C, D @ C_flu @ D, atol=1e-9)
    assert cfg["recording"] == "husky.bag"
    csv_out = tmp_path / "run.csv"
    assert fusion("run", out, "-o", csv_out, "--quiet", "--no-progress") == 0
    last = list(__import__("csv").DictReader(open(csv_out)))[-1]
    # no GPS: the position is dead reckoning on wheel speed (0.05 m/s white) and the IMU's heading (0.02 rad):
    # over ~25 m, a few decimetres; the launch file's own tolerance is 1 m (NED north = ENU y)
    assert math.hypot(float(last["px"]) - tr.y[-1], float(last["py"]) - tr.x[-1]) < 1.0
    assert s > 0


def test_a_sensor_that_fuses_nothing_is_left_out_and_others_kept(tmp_path, capsys):
    params = {"two_d_mode": True,
              "twist0": "/t", "twist0_config": [True] * 6 + [False] * 9,            # pose axes: a twist has none
              "imu0": "/i", "imu0_config": [False] * 3 + [True, True] + [False] * 10,   # roll, pitch: 2-D drops them
              "odom0": "/o", "odom0_config": [True, True] + [False] * 13}
    f = tmp_path / "p.yaml"
    f.write_text(yaml.safe_dump(params))
    cfg, out = _translate(tmp_path, f)
    assert list(cfg["sensors"]) == ["o"]
    err = capsys.readouterr().err
    assert "twist0_config: selects nothing a twist message has" in err
    assert "imu0_config: selects nothing an imu message has outside two_d_mode" in err
    from fusion.config import load_system

    load_system(out)        # wires: every model builds
