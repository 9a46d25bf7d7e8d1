"""Every sensor of an imported flight log on one clock, and the flight's events in the header: small logs of
each layout written here (an older ArduPilot GPS whose ``TimeMS`` is GPS time and ``T`` the boot clock, the
newer one with ``TimeUS``/``GMS``/``GWk``; an older PX4 ``sensor_combined`` with the magnetometer and
barometer inside it), the expected values being the ones written and the UTC instant computed here from
the GPS week by Unix-epoch arithmetic (a second method beside the importer's datetime one)."""
from __future__ import annotations

import datetime as dt

import numpy as np

from dataflash_builder import DataflashWriter
from import_helpers import Recording, fusion_import, one_error_line
from ulog_builder import UlogWriter

WEEK, TOW_MS = 1875, 200_000_000           # GPS week and time of week (ms) of the first fix
OLD_GPS = ("BIHBcLLeeEefI", "Status,TimeMS,Week,NSats,HDop,Lat,Lng,RelAlt,Alt,Spd,GCrs,VZ,T")


def _utc(boot_s: float, week: int, tow_ms: int, leap: int) -> str:
    """UTC at boot time 0 from a fix at ``boot_s`` with GPS ``week``/``tow_ms`` (GPS epoch = Unix 315964800)."""
    unix = 315_964_800 + week * 604_800 + tow_ms / 1e3 - leap - boot_s
    return dt.datetime.fromtimestamp(unix, dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _old_copter(path, gps_boot_ms=None):
    """A Copter 3.3-like log (no FMTU): IMU at 50 Hz from 11.46 s, the older GPS at 5 Hz (boot clock in ``T``),
    EV, MODE and ERR records. ``gps_boot_ms``: the boot times written in ``T`` (default: the IMU's clock)."""
    w = DataflashWriter(units=False)
    w.declare("IMU", "QffffffIIfBB", "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,ErrG,ErrA,Temp,GyHlt,AcHlt")
    w.declare("GPS", *OLD_GPS)
    w.declare("EV", "QB", "TimeUS,Id")
    w.declare("MODE", "QMB", "TimeUS,Mode,ModeNum")
    w.declare("ERR", "QBB", "TimeUS,Subsys,ECode")
    boot = []
    for k in range(250):
        t_us = 11_460_000 + 20_000 * k
        w.write("IMU", TimeUS=t_us, AccZ=-9.81, GyrX=0.01)
        if k % 10 == 0:
            j = k // 10
            t_ms = t_us // 1000 if gps_boot_ms is None else gps_boot_ms + 200 * j
            boot.append(t_ms / 1e3)
            w.write("GPS", Status=3, TimeMS=TOW_MS + 200 * j, Week=WEEK, NSats=10, HDop=0.8, Lat=-35.36 + 1e-6 * j,
                    Lng=149.16, RelAlt=1.0, Alt=585.0, Spd=2.0, GCrs=90.0, VZ=-0.1, T=t_ms)
        if k == 20:
            w.write("MODE", TimeUS=t_us, Mode=5, ModeNum=5)
        if k == 30:
            w.write("EV", TimeUS=t_us, Id=10)
        if k == 200:
            w.write("ERR", TimeUS=t_us, Subsys=6, ECode=1)
        if k == 240:
            w.write("EV", TimeUS=t_us, Id=11)
    w.save(path)
    return np.array(boot)


def test_older_gps_layout_takes_its_boot_clock_from_T(tmp_path, capsys):
    boot = _old_copter(tmp_path / "old.bin")
    assert fusion_import(tmp_path / "old.bin", "-o", tmp_path / "old.log") == 0
    rec = Recording(tmp_path / "old.log")
    np.testing.assert_allclose(rec.times("gps"), boot, atol=1e-9)     # not the time of week (200,000 s)
    imu = rec.times("imu")
    assert imu[0] <= rec.times("gps")[0] and rec.times("gps")[-1] <= imu[-1]
    # GPS - UTC = 17 s in 2015-2016 (week 1875 is 2015-12-13)
    assert rec.header.meta["start_utc"] == _utc(boot[0], WEEK, TOW_MS, 17)


def test_older_gps_layout_nmea_date_from_the_gps_week(tmp_path):
    import pynmea2

    boot = _old_copter(tmp_path / "old.bin")
    assert fusion_import(tmp_path / "old.bin", "-o", tmp_path / "n.log", "--gps", "nmea") == 0
    rmc = [pynmea2.parse(r[0]) for r in Recording(tmp_path / "n.log").rows["gps"] if r[0].startswith("$GPRMC")]
    first = dt.datetime.strptime(_utc(boot[0], WEEK, TOW_MS, 17), "%Y-%m-%dT%H:%M:%S.%fZ") + \
        dt.timedelta(seconds=float(boot[0]))
    assert rmc and rmc[0].datestamp == first.date()


def test_flight_events_in_the_header(tmp_path):
    _old_copter(tmp_path / "old.bin")
    assert fusion_import(tmp_path / "old.bin", "-o", tmp_path / "old.log") == 0
    said = [c for c in Recording(tmp_path / "old.log").comments if c.startswith("# message ")]
    assert said == ["# message 11.860: MODE LOITER", "# message 12.060: ARMED",
                    "# message 15.460: FAILSAFE battery code 1", "# message 16.260: DISARMED"]


def test_a_sensor_off_the_imu_clock_is_refused(tmp_path, capsys):
    _old_copter(tmp_path / "off.bin", gps_boot_ms=603_882_000)      # GPS time where the boot clock should be
    assert fusion_import(tmp_path / "off.bin", "-o", tmp_path / "off.log") == 2
    line = one_error_line(capsys)
    assert "gps: its samples span t 603882.000..603886.800 s" in line and "t 11.460..16.440 s" in line, line
    assert not (tmp_path / "off.log").exists()


def test_partial_says_what_was_cut(tmp_path, capsys):
    _old_copter(tmp_path / "full.bin")
    data = (tmp_path / "full.bin").read_bytes()
    (tmp_path / "cut.bin").write_bytes(data[:-7])
    assert fusion_import(tmp_path / "cut.bin", "-o", tmp_path / "cut.log", "--partial") == 0
    err = capsys.readouterr().err
    assert "truncated: the last message, at byte" in err and "cut short by the end of the file" in err
    partial = Recording(tmp_path / "cut.log").header.meta["partial"]
    assert "truncated" in partial and f"at byte {len(data) - 7}" in partial and "data end at t" in partial


def _old_px4(path, rate_hz: float = 10.0, integral_us: int = 4000):
    """An older PX4 log: ``sensor_combined`` with magnetometer_ga and baro_alt_meter inside it (a new
    magnetometer sample every other row), logged at ``rate_hz`` with ``gyro_integral_dt`` of ``integral_us``,
    and ``vehicle_status`` (armed at row 5, mode POSCTL at row 8, disarmed at row 30)."""
    w = UlogWriter(start_us=1_000_000)
    w.topic("sensor_combined", [("float[3]", "gyro_rad"), ("uint32_t", "gyro_integral_dt"),
                                ("int32_t", "accelerometer_timestamp_relative"), ("float[3]", "accelerometer_m_s2"),
                                ("uint32_t", "accelerometer_integral_dt"),
                                ("int32_t", "magnetometer_timestamp_relative"), ("float[3]", "magnetometer_ga"),
                                ("int32_t", "baro_timestamp_relative"), ("float", "baro_alt_meter"),
                                ("float", "baro_temp_celcius")])
    w.topic("vehicle_status", [("uint8_t", "nav_state"), ("uint8_t", "arming_state"), ("bool", "failsafe")])
    w.subscribe("sensor_combined")
    w.subscribe("vehicle_status")
    step = int(1e6 / rate_hz)
    mags = []
    for k in range(40):
        ts = 1_000_000 + step * k
        m = [0.2 + 0.001 * (k // 2), 0.01, 0.4]
        if k % 2 == 0:
            mags.append(((ts - 500 - 1_000_000) / 1e6, m))
        w.data("sensor_combined", timestamp=ts, gyro_rad=[0.5, 0.0, 0.0], gyro_integral_dt=integral_us,
               accelerometer_m_s2=[0.0, 0.0, -9.81], accelerometer_integral_dt=integral_us,
               magnetometer_timestamp_relative=-500 - (k % 2) * step, magnetometer_ga=m,
               baro_timestamp_relative=-100, baro_alt_meter=100.0 + k, baro_temp_celcius=20.0)
        if k in (0, 5, 8, 30):
            w.data("vehicle_status", timestamp=ts, nav_state=2 if k >= 8 else 0,
                   arming_state=2 if 5 <= k < 30 else 1, failsafe=False)
    w.save(path)
    return mags, step


def test_older_sensor_combined_magnetometer_and_baro(tmp_path, capsys):
    mags, step = _old_px4(tmp_path / "old.ulg")
    assert fusion_import(tmp_path / "old.ulg", "-o", tmp_path / "old.log") == 0
    assert "not in the log: mag" not in capsys.readouterr().err
    rec = Recording(tmp_path / "old.log")
    np.testing.assert_allclose(rec.times("mag"), [t for t, _ in mags], atol=1e-9)   # each sample once
    np.testing.assert_allclose(rec.values("mag"), np.array([m for _, m in mags]) * 100.0, rtol=1e-6)  # G -> uT
    np.testing.assert_allclose(rec.column("baro", "alt"), 100.0 + np.arange(40), atol=1e-5)
    said = [c for c in rec.comments if c.startswith("# message ")]
    assert said == ["# message 0.000: MODE MANUAL", f"# message {5 * step / 1e6:.3f}: ARMED", f"# message {8 * step / 1e6:.3f}: MODE POSCTL",
                    f"# message {30 * step / 1e6:.3f}: DISARMED"]


def test_imu_coverage_in_the_header(tmp_path):
    _old_px4(tmp_path / "low.ulg", rate_hz=10.0, integral_us=4000)
    assert fusion_import(tmp_path / "low.ulg", "-o", tmp_path / "low.log") == 0
    meta = Recording(tmp_path / "low.log").header.meta
    # 4 ms integrated of every 100 ms; 0.5 rad/s held over 0.1 s is 2.86 deg a sample
    assert float(meta["imu_coverage_fraction"]) == np.float64(0.04).round(4)
    assert abs(float(meta["imu_rotation_per_sample_deg"]) - np.degrees(0.05)) <= 0.005   # 3 digits written


def test_initial_attitude_is_the_reference_at_the_first_accepted_fix(tmp_path):
    """The filter of a config with initial.from_sensor: gps starts at the first accepted fix: the attitude to
    start from is the reference's then, not at the log's first sample (here 3 fixes and 40 deg of yaw earlier)."""
    from scipy.spatial.transform import Rotation
    from test_dataflash import _flight

    w, v = _flight()
    w.save(tmp_path / "f.bin")
    assert fusion_import(tmp_path / "f.bin", "-o", tmp_path / "f.log") == 0
    rec = Recording(tmp_path / "f.log")
    k = int(np.flatnonzero(v["status"] >= 3)[0])            # the first fix the gps_fields decoder accepts
    np.testing.assert_allclose(rec.times("initial_attitude"), [v["t"][k] - 1e-6], atol=1e-9)
    rpy = np.round(v["rpy"][k], 2)                          # ATT in centidegrees, at the fix's own time
    want = Rotation.from_euler("ZYX", np.radians(rpy[::-1])).as_quat()[[3, 0, 1, 2]]
    got = rec.values("initial_attitude")[0]
    assert abs(abs(float(np.dot(got, want))) - 1.0) < 1e-9


def test_validate_refuses_a_latency_beyond_max_latency(tmp_path, capsys):
    from import_helpers import ROOT
    from fusion.cli import main

    text = (ROOT / "configs" / "ardupilot_ins_gps_mag.yaml").read_text()
    text = text.replace("recording: ../recordings", f"recording: {ROOT}/recordings")
    assert "time_offset: -0.2 " in text and "max_latency: 0.25 " in text    # the config models the GPS lag
    bad = text.replace("max_latency: 0.25 ", "max_latency: 0.1 ")
    (tmp_path / "bad.yaml").write_text(bad)
    assert main(["validate", str(tmp_path / "bad.yaml")]) == 2
    err = capsys.readouterr().err
    assert "bad.yaml" in err and "time_offset" in err and "scheduler.max_latency (0.1 s)" in err, err
    (tmp_path / "good.yaml").write_text(text)
    assert main(["validate", str(tmp_path / "good.yaml")]) == 0
