"""``fusion import`` of a real PX4 ULog (../shared/logs/px4_sample_log_small.ulg), checked against the values
pyulog reads from the same file directly, and the unit conversions by their definitions."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from import_helpers import Recording, fusion_import, need_px4_log, one_error_line

import pyulog  # noqa: E402  a dependency: a missing one is a failure, not a skip


@pytest.fixture(scope="module")
def px4(tmp_path_factory):
    """(imported Recording, pyulog's ULog of the same file)."""
    src = need_px4_log()
    out = tmp_path_factory.mktemp("px4") / "px4.log"
    assert fusion_import(src, "-o", out) == 0
    return Recording(out), pyulog.ULog(str(src))


def _data(ulog, name):
    return ulog.get_dataset(name, 0).data


def _t(ulog, d):
    return (d.get("timestamp_sample", d["timestamp"]).astype(np.int64) - ulog.start_timestamp) / 1e6


def test_imu_is_sensor_combined_in_si_and_frd(px4):
    rec, ulog = px4
    d = _data(ulog, "sensor_combined")
    assert rec.header.fields["imu"] == ("ax", "ay", "az", "gx", "gy", "gz")
    assert len(rec.times("imu")) == len(d["timestamp"])
    np.testing.assert_allclose(rec.times("imu"), _t(ulog, d), atol=1e-6)
    want = np.column_stack([d[f"accelerometer_m_s2[{i}]"] for i in range(3)] + [d[f"gyro_rad[{i}]"] for i in range(3)])
    np.testing.assert_allclose(rec.values("imu"), want, rtol=1e-7, atol=1e-12)
    # FRD with specific force: the vehicle starts at rest on the ground, so az ~ -g
    assert -10.5 < np.median(rec.column("imu", "az")[:50]) < -9.0


def test_gps_integer_layout_converted_by_its_definition(px4):
    rec, ulog = px4
    d = _data(ulog, "vehicle_gps_position")
    ok = d["fix_type"] >= 2
    assert len(rec.times("gps")) == ok.sum()
    np.testing.assert_allclose(rec.column("gps", "lat"), d["lat"][ok] * 1e-7, atol=1e-10)   # 1e-7 deg units
    np.testing.assert_allclose(rec.column("gps", "lon"), d["lon"][ok] * 1e-7, atol=1e-10)
    np.testing.assert_allclose(rec.column("gps", "alt"), d["alt"][ok] * 1e-3, atol=1e-9)    # mm
    for f, src in (("vn", "vel_n_m_s"), ("ve", "vel_e_m_s"), ("vd", "vel_d_m_s"), ("hacc", "eph"), ("vacc", "epv")):
        np.testing.assert_allclose(rec.column("gps", f), d[src][ok], rtol=1e-7)
    np.testing.assert_array_equal(rec.column("gps", "nsat"), d["satellites_used"][ok])
    np.testing.assert_allclose(rec.times("gps"), _t(ulog, d)[ok], atol=1e-6)


def test_mag_gauss_to_microtesla(px4):
    rec, ulog = px4
    d = _data(ulog, "vehicle_magnetometer")
    want = np.column_stack([d[f"magnetometer_ga[{i}]"] for i in range(3)]) * 100.0   # 1 G = 1e-4 T = 100 uT
    np.testing.assert_allclose(rec.values("mag"), want, rtol=1e-7)
    assert any("mag units: uT" in c for c in rec.comments)
    norm = np.linalg.norm(rec.values("mag"), axis=1)
    assert 20 < np.median(norm) < 70   # the Earth's field is 25-65 uT


def test_baro_from_vehicle_air_data(px4):
    rec, ulog = px4
    d = _data(ulog, "vehicle_air_data")
    np.testing.assert_allclose(rec.column("baro", "pressure"), d["baro_pressure_pa"], rtol=1e-7)
    np.testing.assert_allclose(rec.column("baro", "alt"), d["baro_alt_meter"], rtol=1e-7)


def _slerp(q0, q1, tau):
    """Closed-form slerp of unit quaternions (independent of scipy)."""
    if np.dot(q0, q1) < 0:
        q1 = -q1
    c = np.clip(np.dot(q0, q1), -1, 1)
    th = np.arccos(c)
    if th < 1e-9:
        return q0
    return (np.sin((1 - tau) * th) * q0 + np.sin(tau * th) * q1) / np.sin(th)


def test_reference_is_the_ekf_output_with_only_its_valid_elements(px4):
    rec, ulog = px4
    lp = _data(ulog, "vehicle_local_position")
    # which elements the EKF flags valid anywhere in this log decides the columns (this log: no horizontal fix)
    want = ([] if not lp["xy_valid"].any() else ["px", "py"]) + (["pz"] if lp["z_valid"].any() else []) + \
           ([] if not lp["v_xy_valid"].any() else ["vx", "vy"]) + (["vz"] if lp["v_z_valid"].any() else []) + \
           ["qw", "qx", "qy", "qz"]
    assert rec.header.fields["reference"] == tuple(want)
    keep = np.ones(len(lp["timestamp"]), bool)
    for f in ("xy_valid", "z_valid", "v_xy_valid", "v_z_valid"):
        if lp[f].any():
            keep &= lp[f].astype(bool)
    t = rec.times("reference")
    np.testing.assert_allclose(t, _t(ulog, lp)[keep], atol=1e-6)
    # not tied to the globe in this log: re-expressed about the recording's origin (the first GPS fix with a
    # 3-D fix and >= 6 satellites) by the EKF's own position then (fusion.importers.flight)
    ok = (rec.column("gps", "fix") >= 3) & (rec.column("gps", "nsat") >= 6)
    t_fix0 = rec.times("gps")[ok][0]
    z = lp["z"][keep].astype(float)
    np.testing.assert_allclose(rec.column("reference", "pz"), z - np.interp(t_fix0, t, z), rtol=1e-6, atol=2e-6)
    np.testing.assert_allclose(rec.column("reference", "vz"), lp["vz"][keep], rtol=1e-7)
    att = _data(ulog, "vehicle_attitude")
    ta = _t(ulog, att)
    qa = np.column_stack([att[f"q[{i}]"] for i in range(4)]).astype(float)
    q = rec.values("reference")[:, -4:]
    for k in range(0, len(t), 7):
        j = np.searchsorted(ta, t[k], side="right") - 1
        if j < 0 or j + 1 >= len(ta):
            continue
        expect = _slerp(qa[j], qa[j + 1], (t[k] - ta[j]) / (ta[j + 1] - ta[j]))
        assert min(np.abs(q[k] - expect).max(), np.abs(q[k] + expect).max()) < 2e-6, k


def test_header_names_source_vehicle_origin_and_times_are_sorted(px4):
    rec, ulog = px4
    meta = rec.header.meta
    assert meta["source"].startswith("px4_sample_log_small.ulg")
    assert ulog.msg_info_dict["ver_hw"] in meta["vehicle"]
    lat, lon, alt = map(float, meta["origin"].split())
    g = _data(ulog, "vehicle_gps_position")
    i = np.flatnonzero(g["fix_type"] >= 2)[0]
    assert (lat, lon, alt) == pytest.approx((g["lat"][i] * 1e-7, g["lon"][i] * 1e-7, g["alt"][i] * 1e-3), abs=1e-9)
    assert np.all(np.diff(rec.order) >= 0)
    for m in ulog.logged_messages:          # the flight's events, to choose --start/--end by
        assert f"# message {(m.timestamp - ulog.start_timestamp) / 1e6:.3f}: {m.message}" in rec.comments


def test_time_slice_and_selected_sensors(tmp_path):
    src = need_px4_log()
    out = tmp_path / "cut.log"
    assert fusion_import(src, "-o", out, "--start", "2", "--end", "4.5", "--sensors", "imu", "gps") == 0
    rec = Recording(out)
    assert set(rec.t) == {"imu", "gps"}
    ulog = pyulog.ULog(str(src), ["sensor_combined"])
    t = _t(ulog, _data(ulog, "sensor_combined"))
    ti = rec.times("imu")
    assert len(ti) == np.sum((t >= 2) & (t <= 4.5)) and ti.min() >= 2 and ti.max() <= 4.5
    assert rec.times("gps").min() >= 2 and rec.times("gps").max() <= 4.5


def test_truncated_log_is_one_error_or_imported_with_partial(tmp_path, capsys, px4):
    data = need_px4_log().read_bytes()
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(data[: len(data) * 2 // 3 + 1])
    assert fusion_import(cut, "-o", tmp_path / "a.log") == 2
    line = one_error_line(capsys)
    assert "truncated" in line and "cut.ulg" in line and "--partial" in line
    assert not (tmp_path / "a.log").exists()
    assert fusion_import(cut, "-o", tmp_path / "a.log", "--partial") == 0
    n = len(Recording(tmp_path / "a.log").times("imu"))
    full = len(px4[0].times("imu"))
    assert 0.4 * full < n < full


@pytest.mark.parametrize("content,what", [(b"", "ULog"), (b"\x00" * 600, "ULog"), (b"ULog\x01\x12\x35" + b"\xff" * 40, "")])
def test_not_a_ulog_is_one_error(tmp_path, capsys, content, what):
    bad = tmp_path / "bad.ulg"
    bad.write_bytes(content)
    assert fusion_import(bad, "-o", tmp_path / "x.log") == 2
    line = one_error_line(capsys)
    assert "bad.ulg" in line and what in line


def test_header_cut_log_is_one_error(tmp_path, capsys):
    data = need_px4_log().read_bytes()
    cut = tmp_path / "head.ulg"
    cut.write_bytes(data[:3000])
    assert fusion_import(cut, "-o", tmp_path / "x.log") == 2
    assert "head.ulg" in one_error_line(capsys)


def test_output_rules(tmp_path, capsys):
    src = need_px4_log()
    out = tmp_path / "o.log"
    out.write_text("keep me\n")
    assert fusion_import(src, "-o", out, "--sensors", "gps") == 2
    assert "--force" in one_error_line(capsys) and out.read_text() == "keep me\n"
    assert fusion_import(src, "-o", out, "--sensors", "gps", "--force") == 0
    assert Recording(out).times("gps").size > 0
    capsys.readouterr()
    assert fusion_import(src, "-o", src, "--force", "--sensors", "gps") == 2
    assert "input" in one_error_line(capsys)
    assert [p.name for p in tmp_path.iterdir()] == ["o.log"]   # no temporary file left behind


def test_unknown_sensor_and_missing_topic_are_one_error(tmp_path, capsys):
    src = need_px4_log()
    assert fusion_import(src, "-o", tmp_path / "x.log", "--sensors", "lidar") == 2
    assert "lidar" in one_error_line(capsys)
    assert fusion_import(src, "-o", tmp_path / "x.log", "--start", "100") == 2
    assert "no samples" in one_error_line(capsys)


def test_newer_layouts_float_gps_sensor_mag_and_mbar_baro(tmp_path):
    """Layouts the shipped log lacks, in a ULog written here: sensor_gps with float degrees and metres,
    sensor_mag (no vehicle_magnetometer), sensor_baro in mbar (older firmware), vehicle_attitude only."""
    from ulog_builder import UlogWriter

    w = UlogWriter(start_us=5_000_000)
    w.info("sys_name", "PX4")
    w.topic("sensor_gps", [("uint64_t", "timestamp_sample"), ("double", "latitude_deg"), ("double", "longitude_deg"),
                           ("double", "altitude_msl_m"), ("float", "eph"), ("float", "epv"), ("float", "vel_n_m_s"),
                           ("float", "vel_e_m_s"), ("float", "vel_d_m_s"), ("uint8_t", "fix_type"),
                           ("uint8_t", "satellites_used")])
    w.topic("sensor_mag", [("float", "x"), ("float", "y"), ("float", "z")])
    w.topic("sensor_baro", [("float", "pressure"), ("float", "temperature")])
    w.topic("vehicle_attitude", [("float[4]", "q")])
    for name in ("sensor_gps", "sensor_mag", "sensor_baro", "vehicle_attitude"):
        w.subscribe(name)
    lat0, lon0 = 47.397742123456, 8.545594987654
    for k in range(10):
        t = 5_000_000 + 100_000 * k
        w.data("sensor_gps", timestamp=t + 900, timestamp_sample=t, latitude_deg=lat0 + 1e-7 * k,
               longitude_deg=lon0 - 2e-7 * k, altitude_msl_m=488.25 + 0.1 * k, eph=0.8, epv=1.5, vel_n_m_s=0.5,
               vel_e_m_s=-0.25, vel_d_m_s=0.125, fix_type=1 if k == 0 else 3, satellites_used=14)
        w.data("sensor_mag", timestamp=t, x=0.21, y=0.015, z=0.43)
        w.data("sensor_baro", timestamp=t, pressure=955.5 + k, temperature=30.5)
        w.data("vehicle_attitude", timestamp=t, q=[0.5, 0.5, -0.5, 0.5])
    w.save(tmp_path / "new.ulg")
    assert fusion_import(tmp_path / "new.ulg", "-o", tmp_path / "new.log") == 0
    rec = Recording(tmp_path / "new.log")
    k = np.arange(1, 10)                                   # the first sample has no fix
    np.testing.assert_allclose(rec.times("gps"), 0.1 * k, atol=1e-9)    # timestamp_sample, from the start
    np.testing.assert_allclose(rec.column("gps", "lat"), lat0 + 1e-7 * k, atol=1e-9)
    np.testing.assert_allclose(rec.column("gps", "lon"), lon0 - 2e-7 * k, atol=1e-9)
    np.testing.assert_allclose(rec.column("gps", "alt"), 488.25 + 0.1 * k, atol=1e-3)
    np.testing.assert_allclose(rec.values("mag")[0], np.float32([0.21, 0.015, 0.43]) * 100.0, rtol=1e-6)
    np.testing.assert_allclose(rec.column("baro", "pressure"), (955.5 + np.arange(10)) * 100.0, rtol=1e-7)
    assert rec.header.fields["reference"] == ("qw", "qx", "qy", "qz")
    np.testing.assert_allclose(rec.values("reference")[0], [0.5, 0.5, -0.5, 0.5])


def test_gps_as_nmea_sentences_read_back_by_pynmea2(tmp_path, px4):
    import pynmea2
    src = need_px4_log()
    out = tmp_path / "nmea.log"
    assert fusion_import(src, "-o", out, "--sensors", "gps", "--gps", "nmea") == 0
    rec = Recording(out)
    assert rec.header.fields["gps"] == ("nmea",)
    sentences = [pynmea2.parse(row[0], check=True) for row in rec.rows["gps"]]   # checksums verified
    gga = [s for s in sentences if s.sentence_type == "GGA"]
    rmc = [s for s in sentences if s.sentence_type == "RMC"]
    d = _data(px4[1], "vehicle_gps_position")
    ok = d["fix_type"] >= 2
    assert len(gga) == len(rmc) == ok.sum()
    np.testing.assert_allclose([s.latitude for s in gga], d["lat"][ok] * 1e-7, atol=2e-9)
    np.testing.assert_allclose([s.longitude for s in gga], d["lon"][ok] * 1e-7, atol=2e-9)
    np.testing.assert_allclose([float(s.altitude) for s in gga], d["alt"][ok] * 1e-3, atol=1e-9)
    np.testing.assert_allclose([float(s.geo_sep) for s in gga], (d["alt_ellipsoid"][ok] - d["alt"][ok]) * 1e-3,
                               atol=1e-9)
    speed = np.hypot(d["vel_n_m_s"][ok], d["vel_e_m_s"][ok]) / (1852 / 3600)
    np.testing.assert_allclose([float(s.spd_over_grnd) for s in rmc], speed, atol=1e-3)
    utc = d["time_utc_usec"][ok][0] / 1e6
    first = gga[0].timestamp
    assert abs((first.hour * 3600 + first.minute * 60 + first.second + first.microsecond / 1e6) - utc % 86400) < 0.011


def test_earth_field_in_ned_from_the_onboard_attitude(tmp_path):
    """vehicle_magnetometer samples of a known NED field seen through a turning attitude: the header's
    earth_field_ned is that field (the samples rotated back by vehicle_attitude, slerped to their times)."""
    from scipy.spatial.transform import Rotation
    from ulog_builder import UlogWriter

    m_n = np.array([0.15, 0.01, 0.48])                     # G, NED (about 50 uT, inclination ~72 deg)
    w = UlogWriter(start_us=1_000_000)
    w.topic("vehicle_magnetometer", [("float[3]", "magnetometer_ga")])
    w.topic("vehicle_attitude", [("float[4]", "q")])
    w.subscribe("vehicle_magnetometer")
    w.subscribe("vehicle_attitude")
    for k in range(50):
        t = 1_000_000 + 20_000 * k
        rot = Rotation.from_euler("ZYX", [7.0 * k, 3.0, -2.0], degrees=True)     # yawing at 350 deg/s
        w.data("vehicle_attitude", timestamp=t, q=rot.as_quat()[[3, 0, 1, 2]])
        if k % 2 and k < 49:                                # the magnetometer halfway between two attitudes
            q0 = rot.as_quat()[[3, 0, 1, 2]]
            q1 = Rotation.from_euler("ZYX", [7.0 * (k + 1), 3.0, -2.0], degrees=True).as_quat()[[3, 0, 1, 2]]
            mid = Rotation.from_quat(_slerp(q0, q1, 0.5)[[1, 2, 3, 0]])      # closed-form slerp (above)
            w.data("vehicle_magnetometer", timestamp=t + 10_000, magnetometer_ga=mid.inv().apply(m_n))
    w.save(tmp_path / "f.ulg")
    assert fusion_import(tmp_path / "f.ulg", "-o", tmp_path / "f.log", "--sensors", "mag") == 0
    rec = Recording(tmp_path / "f.log")
    line = next(c for c in rec.comments if c.startswith("# mag earth_field_ned:"))
    np.testing.assert_allclose([float(x) for x in line.split(":")[1].split()], m_n * 100.0, atol=2e-3)


def test_full_disk_is_one_error_and_leaves_no_file(tmp_path, capsys):
    """The importer writes through fusion.outputs: /dev/full (a device, written in place) fails in one line."""
    src = need_px4_log()
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full on this system")
    assert fusion_import(src, "-o", "/dev/full", "--sensors", "imu") == 2
    line = one_error_line(capsys)
    assert "/dev/full" in line and "space" in line.lower()


def test_a_velocity_the_receiver_flags_invalid_is_not_fused(tmp_path, capsys):
    """vel_ned_valid is checked per sample, not for 'ever true' (which would write and fuse the
    velocities of the samples flagged invalid). They are written with vok 0 (the 13-value gps layout) and the
    gps_fields decoder makes those epochs position only; the NMEA route writes them as GGA alone."""
    from ulog_builder import UlogWriter

    from fusion.api import Message
    from fusion.importers.gps_decoder import GpsFieldsDecoder

    w = UlogWriter(start_us=1_000_000)
    w.topic("vehicle_gps_position", [("int32_t", "lat"), ("int32_t", "lon"), ("int32_t", "alt"), ("float", "eph"),
                                     ("float", "epv"), ("float", "hdop"), ("float", "vel_n_m_s"), ("float", "vel_e_m_s"),
                                     ("float", "vel_d_m_s"), ("bool", "vel_ned_valid"), ("uint8_t", "fix_type"),
                                     ("uint8_t", "satellites_used")])
    w.subscribe("vehicle_gps_position")
    for k in range(20):
        w.data("vehicle_gps_position", timestamp=1_000_000 + 200_000 * k, lat=473977420, lon=85455940, alt=488000,
               eph=0.9, epv=1.4, hdop=0.7, vel_n_m_s=2.0, vel_e_m_s=0.0, vel_d_m_s=0.0, vel_ned_valid=k >= 8,
               fix_type=3, satellites_used=14)
    w.save(tmp_path / "v.ulg")
    assert fusion_import(tmp_path / "v.ulg", "-o", tmp_path / "v.log", "--sensors", "gps") == 0
    assert "8 of 20 fix(es) with the velocity flagged invalid" in capsys.readouterr().err
    rec = Recording(tmp_path / "v.log")
    assert rec.header.fields["gps"][-1] == "vok"
    np.testing.assert_array_equal(rec.column("gps", "vok"), [0] * 8 + [1] * 12)
    dec = GpsFieldsDecoder()
    out = [dec.decode(Message(t, "gps", tuple(v))) for t, v in zip(rec.t["gps"], rec.rows["gps"])]
    assert all(np.isnan(o.values[3]) and np.isnan(o.values[4]) for o in out[:8])
    assert all(o.values[3] == pytest.approx(2.0) for o in out[8:])
    assert fusion_import(tmp_path / "v.ulg", "-o", tmp_path / "n.log", "--sensors", "gps", "--gps", "nmea") == 0
    sentences = [r[0][:6] for r in Recording(tmp_path / "n.log").rows["gps"]]
    assert sentences.count("$GPGGA") == 20 and sentences.count("$GPRMC") == 12
