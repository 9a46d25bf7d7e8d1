"""``fusion import`` of ROS 1 and ROS 2 bags (sqlite3 and mcap storage) written by the tests with rosbags'
writers (tests/ros/bagmaker.py): topics by message type, frames ENU/FLU -> NED/FRD, stamps, covariances, tf
mounts, the mapping file, and one clear line for each kind of bad bag."""
from __future__ import annotations

import numpy as np
import pytest

from bagmaker import G, ORIGIN, Spec, storage_file, write_bag
from ros_helpers import Recording, fusion

STORAGES = ("ros1", "sqlite3", "mcap")


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    d = tmp_path_factory.mktemp("bags")
    out = {}
    for s in STORAGES:
        path = d / ("robot.bag" if s == "ros1" else f"robot_{s}")
        tr = write_bag(path, s, duration=10.0)
        out[s] = (storage_file(path, s), tr)
    return out


@pytest.fixture(scope="module")
def imported(bags, tmp_path_factory):
    d = tmp_path_factory.mktemp("logs")
    mp = d / "map.yaml"
    mp.write_text("reference: {topic: /odometry/filtered}\nsensors:\n  wheel: {topic: /wheel/odometry}\n")
    out = {}
    for s, (path, tr) in bags.items():
        log = d / f"{s}.log"
        assert fusion("import", path, "-o", log, "--map", mp) == 0
        out[s] = (Recording(log), tr, log)
    return out


def _body(log_path):
    return [line for line in log_path.read_text().splitlines() if not line.startswith("# source")]


def test_ros1_sqlite3_and_mcap_bags_import_to_the_same_recording(imported):
    ros1 = _body(imported["ros1"][2])
    assert _body(imported["sqlite3"][2]) == ros1
    assert _body(imported["mcap"][2]) == ros1
    rec = imported["ros1"][0]
    assert set(rec.header.fields) == {"imu_data", "wheel", "gps_fix", "reference"}


def test_a_ros2_bag_folder_is_read_as_its_storage_file(bags, tmp_path):
    folder = bags["mcap"][0].parent
    assert fusion("import", folder, "-o", tmp_path / "f.log") == 0
    assert len(Recording(tmp_path / "f.log").times("imu_data")) == 501      # 10 s at 50 Hz, both ends


def test_reference_is_the_truth_in_ned_frd(imported):
    rec, tr, _ = imported["ros1"]
    t = rec.times("reference")
    i = np.rint(t * 200).astype(int)
    # ENU east = NED y, ENU north = NED x; yaw from north clockwise = pi/2 - yaw from east counter-clockwise
    np.testing.assert_allclose(rec.column("reference", "px"), tr.y[i], atol=1e-6)
    np.testing.assert_allclose(rec.column("reference", "py"), tr.x[i], atol=1e-6)
    np.testing.assert_allclose(rec.column("reference", "pz"), 0.0, atol=1e-9)
    yaw = np.angle(np.exp(1j * (np.pi / 2 - tr.yaw[i])))
    np.testing.assert_allclose(np.angle(np.exp(1j * (rec.column("reference", "yaw") - yaw))), 0.0, atol=1e-6)
    # body velocity: forward stays forward; a left turn (ROS +z rate) is a negative FRD yaw rate
    np.testing.assert_allclose(rec.column("reference", "vbx"), tr.v[i], atol=1e-6)
    np.testing.assert_allclose(rec.column("reference", "wz"), -tr.r[i], atol=1e-6)
    # NED velocity = C v_body: north = v cos(yaw_enu)... east/north swapped
    np.testing.assert_allclose(rec.column("reference", "vx"), tr.v[i] * np.sin(tr.yaw[i]), atol=1e-6)
    np.testing.assert_allclose(rec.column("reference", "vy"), tr.v[i] * np.cos(tr.yaw[i]), atol=1e-6)


def test_imu_is_frd_with_gravity_down_and_its_covariances(imported):
    rec = imported["ros1"][0]
    sd = Spec()
    az = rec.column("imu_data", "az")
    # at rest on flat ground the FRD accelerometer reads -g on z (ROS FLU: +g); noise sd 0.05, 2001 samples
    assert abs(np.mean(az) + G) < 5 * sd.accel_sd / np.sqrt(len(az))
    np.testing.assert_allclose(rec.column("imu_data", "ca00"), sd.accel_sd ** 2)
    np.testing.assert_allclose(rec.column("imu_data", "cq22"), sd.yaw_sd ** 2)
    np.testing.assert_allclose(rec.column("imu_data", "ca01"), 0.0)
    assert "imu_data mount: lever_arm 0.1 0 -0.2 m" in " ".join(rec.comments)


def test_gps_in_ned_about_the_first_fix_with_its_covariance(imported):
    rec, tr, _ = imported["ros1"]
    lat, lon, _ = (float(v) for v in rec.meta("origin").split())
    assert abs(lat - ORIGIN[0]) < 1e-4 and abs(lon - ORIGIN[1]) < 1e-4    # within ~10 m: the first fix's noise
    t = rec.times("gps_fix")
    i = np.rint(t * 200).astype(int)
    north = rec.column("gps_fix", "px")
    first = north[0] - tr.y[0]
    # the fix's noise is 0.5 m a coordinate (Spec.gps_sd): 201 fixes, mean error within 5 sd of the mean
    assert abs(np.mean(north - tr.y[i] - first)) < 5 * 0.5 * np.sqrt(2 / len(t))
    np.testing.assert_allclose(rec.column("gps_fix", "c00"), 0.25)


def test_stamp_delay_is_reported_per_topic(imported):
    rec = imported["ros1"][0]
    assert rec.meta("gps_fix receive_minus_stamp_s").startswith("median 0.030000")
    assert rec.meta("imu_data receive_minus_stamp_s").startswith("median 0.010000")
    assert "NED" in rec.meta("frame")


def test_static_tf_rotation_gives_the_mount_in_frd(tmp_path):
    # robot_localization's Husky bag test mounts its IMU at 0 -0.3 0.52 turned about x; here roll +90 deg (FLU)
    s = np.sqrt(0.5)
    bag = tmp_path / "tf.bag"
    write_bag(bag, "ros1", duration=2.0, tf_extra=[("base_link", "imu_link", (0.0, -0.3, 0.52), (s, s, 0.0, 0.0))])
    assert fusion("import", bag, "-o", tmp_path / "o.log") == 0
    rec = Recording(tmp_path / "o.log")
    x, y, z, roll, pitch, yaw = (float(v) for v in rec.meta("tf base_link imu_link").split()[:6])
    assert (x, y, z) == (0.0, -0.3, 0.52)
    np.testing.assert_allclose([roll, pitch, yaw], [np.pi / 2, 0.0, 0.0], atol=1e-12)
    words = rec.meta("imu_data mount").split()
    # FLU (0, -0.3, 0.52) is FRD (0, 0.3, -0.52); a rotation about x is the same about FRD's x (D Rx D = Rx)
    np.testing.assert_allclose([float(v) for v in words[1:4]], [0.0, 0.3, -0.52], atol=1e-12)
    np.testing.assert_allclose([float(v) for v in words[8:12]], [s, s, 0.0, 0.0], atol=1e-9)


def test_mounts_repeated_on_tf_are_static_and_motion_is_not(tmp_path):
    # ROS 1's static_transform_publisher repeats a mount on /tf; odom -> base_link there is the robot's motion
    bag = tmp_path / "tf.bag"
    write_bag(bag, "ros1", Spec(tf_on_tf=True), duration=3.0)
    assert fusion("import", bag, "-o", tmp_path / "o.log") == 0
    rec = Recording(tmp_path / "o.log")
    assert rec.meta("tf base_link imu_link").startswith("0.1 0 0.2 0 0 0")
    assert not any(c.startswith("# tf odom base_link") for c in rec.comments)
    assert rec.meta("imu_data mount").startswith("lever_arm 0.1 0 -0.2 m")


def test_magnetic_field_in_ut_frd_and_ranges_out_of_range_dropped(tmp_path, capsys):
    bag = tmp_path / "m.bag"
    write_bag(bag, "ros1", Spec(mag_range=True), duration=8.0)
    assert fusion("import", bag, "-o", tmp_path / "o.log") == 0
    rec = Recording(tmp_path / "o.log")
    # ROS FLU tesla (2e-5, 1e-6, -4e-5) -> FRD microtesla (20, -1, 40)
    np.testing.assert_allclose([rec.column("mag", k)[0] for k in ("mx", "my", "mz")], [20.0, -1.0, 40.0])
    r = rec.column("sonar", "range")
    assert len(r) == 6 and np.all(r <= 4.0)       # 9 readings, those at k = 0, 4, 8 past max_range
    assert "sonar (/sonar): 3 messages outside [min_range, max_range] (no detection), dropped" in capsys.readouterr().err


def test_mapping_names_truth_and_maps_another_type(tmp_path):
    bag = tmp_path / "u.bag"
    write_bag(bag, "ros1", Spec(unknown_topic=True), duration=2.0)
    mp = tmp_path / "m.yaml"
    mp.write_text("truth: {topic: /odometry/filtered}\nsensors:\n  battery: {topic: /battery, fields: {volts: data}, "
                  "scale: 2.0, units: V}\n")
    assert fusion("import", bag, "-o", tmp_path / "o.log", "--map", mp) == 0
    rec = Recording(tmp_path / "o.log")
    assert rec.column("battery", "volts")[0] == pytest.approx(24.2)
    assert "truth" in rec.header.fields and "reference" not in rec.header.fields


@pytest.mark.parametrize("spec, words", [
    (Spec(unknown_topic=True), "topic /battery (std_msgs/msg/Float64): a message type without a default mapping"),
    (Spec(empty_topic=True), "topic /unused (sensor_msgs/msg/Imu): no messages"),
    (Spec(zero_stamps=3), "imu_data (/imu/data): 3 messages stamped 0"),
    (Spec(backwards=True), "odometry (/wheel/odometry): header stamps go backwards 1 times"),
    (Spec(zero_cov=True), "all-zero covariance (robot_localization adds 1e-6"),
])
def test_bad_topics_are_one_counted_note_each(tmp_path, capsys, spec, words):
    bag = tmp_path / "b.bag"
    write_bag(bag, "ros1", spec, duration=2.0)
    assert fusion("import", bag, "-o", tmp_path / "o.log") == 0
    err = capsys.readouterr().err.splitlines()
    hits = [e for e in err if words in e]
    assert len(hits) == 1, err
    assert hits[0].startswith("fusion import: ")


@pytest.mark.parametrize("storage", STORAGES)
def test_truncated_bag_is_one_error_line_or_partial(tmp_path, capsys, storage):
    path = tmp_path / ("t.bag" if storage == "ros1" else "t")
    write_bag(path, storage, duration=4.0)
    f = storage_file(path, storage)
    data = f.read_bytes()
    cut = tmp_path / ("cut" + f.suffix)
    cut.write_bytes(data[: len(data) * 2 // 3])
    assert fusion("import", cut, "-o", tmp_path / "o.log") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("fusion import: error: ") and str(cut) in err[0], err
    assert not (tmp_path / "o.log").exists()
    # rosbags reads through the index / summary / database: --partial cannot read a cut one, and says how to
    # rebuild it
    assert fusion("import", cut, "-o", tmp_path / "o.log", "--partial") == 2
    err = capsys.readouterr().err
    assert {"ros1": "rosbag reindex", "mcap": "mcap recover", "sqlite3": ".recover"}[storage] in err


def test_time_span_and_sensors(bags, tmp_path):
    path, _ = bags["ros1"]
    assert fusion("import", path, "-o", tmp_path / "o.log", "--start", "2", "--end", "8", "--sensors", "imu_data") == 0
    rec = Recording(tmp_path / "o.log")
    assert set(rec.header.fields) == {"imu_data"}
    t = rec.times("imu_data")
    assert t.min() == 2.0 and t.max() == 8.0 and len(t) == 301


def test_junk_with_a_bag_suffix_is_one_error_line(tmp_path, capsys):
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 10)
    assert fusion("import", junk, "-o", tmp_path / "o.log") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a readable ROS bag" in err[0], err
