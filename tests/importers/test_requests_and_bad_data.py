"""``fusion import`` on requests it cannot meet and on damaged or odd data: a sensor
asked for by name that the importer cannot write is one exit-2 line, never a silent drop; corrupt samples
are skipped with a warning naming them; row order and the time span do not change what a CSV gives."""
from __future__ import annotations

import numpy as np
import pytest

from dataflash_builder import DataflashWriter
from import_helpers import Recording, fusion_import, one_error_line
from ulog_builder import UlogWriter


def _ulog(path, n: int = 20, valid_from: dict | None = None, flags: dict | None = None, mag: str = "vehicle"):
    """A 10 Hz ULog: vehicle_local_position (+ validity flags), vehicle_attitude, sensor_combined and a
    magnetometer. ``valid_from``: flag -> first valid sample; ``flags``: (sample, flag) -> raw byte."""
    valid_from = valid_from or {}
    flags = flags or {}
    w = UlogWriter(start_us=1_000_000)
    w.info("sys_name", "PX4")
    w.topic("sensor_combined", [("float[3]", "gyro_rad"), ("float[3]", "accelerometer_m_s2")])
    w.topic("vehicle_attitude", [("float[4]", "q")])
    w.topic("vehicle_local_position", [("float", "x"), ("float", "y"), ("float", "z"), ("float", "vx"),
                                       ("float", "vy"), ("float", "vz"), ("bool", "xy_valid"), ("bool", "z_valid"),
                                       ("bool", "v_xy_valid"), ("bool", "v_z_valid")])
    mag_topic = "vehicle_magnetometer" if mag == "vehicle" else "sensor_mag"
    if mag == "vehicle":
        w.topic(mag_topic, [("float[3]", "magnetometer_ga")])
    else:
        w.topic(mag_topic, [("float", "x"), ("float", "y"), ("float", "z")])
    for name in ("sensor_combined", "vehicle_attitude", "vehicle_local_position", mag_topic):
        w.subscribe(name)
    for k in range(n):
        t = 1_000_000 + 100_000 * k
        w.data("sensor_combined", timestamp=t + 1000, gyro_rad=[0.01, 0, 0], accelerometer_m_s2=[0, 0, -9.8])
        c, s = np.cos(0.01 * k), np.sin(0.01 * k)
        w.data("vehicle_attitude", timestamp=t + 2000, q=[c, 0, 0, s])
        vals = {f: k >= valid_from.get(f, 0) for f in ("xy_valid", "z_valid", "v_xy_valid", "v_z_valid")}
        w.data("vehicle_local_position", timestamp=t + 3000, x=0.1 * k, y=0.2 * k, z=-0.3 * k, vx=1.0, vy=2.0,
               vz=-3.0, **vals)
        if mag == "vehicle":
            w.data(mag_topic, timestamp=t + 4000, magnetometer_ga=[0.2, 0.0, 0.4])
        else:
            w.data(mag_topic, timestamp=t + 4000, x=0.2, y=0.0, z=0.4)
    buf = w.buf
    if flags:   # a flag byte that is neither 0 nor 1: the sample is corrupt (struct's '?' cannot write one)
        fields = w.formats["vehicle_local_position"]
        size = {"uint64_t": 8, "float": 4, "bool": 1}
        msg_id = w.ids[("vehicle_local_position", 0)]
        pos, seen = 0, -1
        while pos < len(buf):
            if buf[pos:pos + 3] == b"ULo":
                pos += 16
                continue
            length, kind = int.from_bytes(buf[pos:pos + 2], "little"), buf[pos + 2:pos + 3]
            body = pos + 3
            if kind == b"D" and int.from_bytes(buf[body:body + 2], "little") == msg_id:
                seen += 1
                off = body + 2
                for typ, name in fields:
                    if (seen, name) in flags:
                        buf[off] = flags[(seen, name)] & 0xFF
                    off += size[typ]
            pos = body + length
    w.save(path)


# ----------------------------------------------------------------------------- --sensors
def test_ulog_numbered_sensor_is_one_error_alone_and_in_a_list(tmp_path, capsys):
    _ulog(tmp_path / "a.ulg")
    for names in (["imu2"], ["gps", "imu9"], ["mag2"]):
        assert fusion_import(tmp_path / "a.ulg", "-o", tmp_path / "x.log", "--sensors", *names) == 2
        line = one_error_line(capsys)
        assert "reads only instance 0" in line and names[-1] in line and "empty" not in line, line
    assert not (tmp_path / "x.log").exists()


def _two_imus(path):
    w = DataflashWriter()
    for name in ("IMU", "GPS"):
        w.declare(name)
    for k in range(10):
        t = 1_000_000 + 100_000 * k
        for i in (0, 1):
            w.write("IMU", TimeUS=t + i, I=i, AccZ=-9.8)
        w.write("GPS", TimeUS=t, I=0, Status=3, NSats=10, Lat=-35.0, Lng=149.0, Alt=500.0, GWk=2300, GMS=1000 * k)
    w.save(path)


def test_dataflash_instance_not_in_the_log_is_one_error_alone_and_in_a_list(tmp_path, capsys):
    _two_imus(tmp_path / "a.bin")
    for names in (["imu9"], ["gps", "imu9"], ["imu", "imu3"]):
        assert fusion_import(tmp_path / "a.bin", "-o", tmp_path / "x.log", "--sensors", *names) == 2
        line = one_error_line(capsys)
        assert "not in the log" in line and names[-1] in line and "imu, imu2" in line, line
    assert fusion_import(tmp_path / "a.bin", "-o", tmp_path / "x.log", "--sensors", "gps", "imu2") == 0
    assert set(Recording(tmp_path / "x.log").t) == {"gps", "imu2"}


# ----------------------------------------------------------------------------- ULog validity flags
def _reference_of(tmp_path, capsys, **kw):
    _ulog(tmp_path / "r.ulg", **kw)
    assert fusion_import(tmp_path / "r.ulg", "-o", tmp_path / "r.log", "--force") == 0
    return Recording(tmp_path / "r.log"), capsys.readouterr().err


def test_ulog_corrupt_validity_flags_skip_that_sample_only(tmp_path, capsys):
    rec, err = _reference_of(tmp_path, capsys, flags={(7, "xy_valid"): -44, (7, "v_xy_valid"): 187})
    assert rec.header.fields["reference"] == ("px", "py", "pz", "vx", "vy", "vz", "qw", "qx", "qy", "qz")
    t = rec.times("reference")
    assert len(t) == 19 and not np.any(np.isclose(t, 0.703))       # sample 7 (t 0.703 s) only
    assert "sample 7 (t 0.703 s): xy_valid=-44, v_xy_valid=-69" in err, err   # 187 is int8 -69
    np.testing.assert_allclose(rec.times("initial_attitude"), [0.002], atol=1e-9)   # the first attitude


def test_ulog_element_valid_late_does_not_move_the_others_or_the_initial_attitude(tmp_path, capsys):
    # a horizontal fix only in the last 5 of 20 samples: pz vz q over the whole log, px py vx vy left out, said
    rec, err = _reference_of(tmp_path, capsys, valid_from={"xy_valid": 15, "v_xy_valid": 15})
    assert rec.header.fields["reference"] == ("pz", "vz", "qw", "qx", "qy", "qz")
    assert len(rec.times("reference")) == 20
    assert "xy_valid only in 5 of 20" in err and "--start 1.50" in err, err
    start = err.split("--start ")[1].split()[0]
    assert fusion_import(tmp_path / "r.ulg", "-o", tmp_path / "s.log", "--start", start) == 0
    assert Recording(tmp_path / "s.log").header.fields["reference"][:2] == ("px", "py")   # as the note says
    capsys.readouterr()
    np.testing.assert_allclose(rec.times("initial_attitude"), [0.002], atol=1e-9)
    np.testing.assert_allclose(rec.values("initial_attitude")[0], [1, 0, 0, 0], atol=1e-7)
    # valid from sample 3: every element, from then on; the initial attitude stays the first one
    rec, err = _reference_of(tmp_path, capsys, valid_from={"xy_valid": 3})
    assert rec.header.fields["reference"][:3] == ("px", "py", "pz")
    np.testing.assert_allclose(rec.times("reference")[0], 0.303, atol=1e-9)
    assert "3 of 20 sample(s) at which not all of" in err
    np.testing.assert_allclose(rec.times("initial_attitude"), [0.002], atol=1e-9)
    np.testing.assert_allclose(rec.values("initial_attitude")[0], [1, 0, 0, 0], atol=1e-7)


def test_ulog_raw_sensor_mag_is_warned_on_stderr(tmp_path, capsys):
    _, err = _reference_of(tmp_path, capsys, mag="raw")
    assert "no vehicle_magnetometer" in err and "sensor_mag" in err, err
    _, err = _reference_of(tmp_path, capsys)
    assert "no vehicle_magnetometer" not in err


# ----------------------------------------------------------------------------- findings 7 and 19: CSV row order
def _csv(tmp_path, order):
    rows = [(k, 2.0 + 0.25 * k) for k in range(12)]          # t = 0.25 k s; value 2 + 0.25 k
    body = "".join(f"2024-03-05T10:15:{2.25 + 0.25 * k:06.3f}Z,{v}\n" for k, v in (rows[i] for i in order))
    (tmp_path / "r.csv").write_text("timestamp,r\n" + body)
    (tmp_path / "m.yaml").write_text("time: {column: timestamp, unit: iso, zero: first}\n"
                                     "sensors:\n  uwb: {fields: {range: r}}\n")
    return tmp_path / "r.csv", tmp_path / "m.yaml"


def test_csv_zero_first_is_the_earliest_time_whatever_the_row_order(tmp_path, capsys):
    src, mp = _csv(tmp_path, [1, 0, *range(2, 12)])               # rows 1 and 2 swapped
    assert fusion_import(src, "--map", mp, "-o", tmp_path / "o.log") == 0
    err = capsys.readouterr().err
    rec = Recording(tmp_path / "o.log")
    np.testing.assert_allclose(rec.times("uwb"), 0.25 * np.arange(12), atol=1e-9)
    np.testing.assert_allclose(rec.values("uwb")[:, 0], 2 + 0.25 * np.arange(12))
    assert "r.csv: rows not in time order (line 3: 2024-03-05T10:15:02.250" in err, err
    assert "t = 0 is the earliest time" in err
    assert fusion_import(src, "--map", mp, "-o", tmp_path / "s.log", "--start", "0.25", "--end", "1") == 0   # re-read
    np.testing.assert_allclose(Recording(tmp_path / "s.log").times("uwb"), [0.25, 0.5, 0.75, 1.0], atol=1e-9)
    capsys.readouterr()
    src, mp = _csv(tmp_path, list(range(12)))                     # in order: no note
    assert fusion_import(src, "--map", mp, "-o", tmp_path / "o2.log") == 0
    assert "time order" not in capsys.readouterr().err


def test_csv_end_keeps_a_row_inside_the_span_written_after_a_later_one(tmp_path, capsys):
    order = [0, *range(2, 9), 1, *range(9, 12)]                   # the row of t = 0.25 s after the t = 2.0 s row
    src, mp = _csv(tmp_path, order)
    assert fusion_import(src, "--map", mp, "-o", tmp_path / "o.log", "--end", "1") == 0
    np.testing.assert_allclose(Recording(tmp_path / "o.log").times("uwb"), [0, 0.25, 0.5, 0.75, 1.0], atol=1e-9)
    assert "rows not in time order (line 10" in capsys.readouterr().err


# ----------------------------------------------------------------------------- DataFlash damage
def _ap(n: int = 40, mark: int | None = None):
    """A 10 Hz DataFlash log of IMU + GPS; returns (bytes, offset of IMU message ``mark``)."""
    w = DataflashWriter()
    for name in ("IMU", "GPS"):
        w.declare(name)
    at = None
    for k in range(n):
        t = 1_000_000 + 100_000 * k
        if k == mark:
            at = len(w.buf)
        w.write("IMU", TimeUS=t, I=0, AccZ=-9.8, GyrX=0.001 * k)
        w.write("GPS", TimeUS=t, I=0, Status=3, NSats=10, Lat=-35.0, Lng=149.0, Alt=500.0, GWk=2300, GMS=1000 * k)
    return bytearray(w.buf), at


def test_dataflash_unknown_message_type_is_corruption_and_partial_reads_past_it(tmp_path, capsys):
    data, at = _ap(mark=25)
    data[at + 2] = 0xA9                                 # the type byte of IMU message 25: no FMT declares it
    (tmp_path / "u.bin").write_bytes(bytes(data))
    assert fusion_import(tmp_path / "u.bin", "-o", tmp_path / "u.log") == 2
    line = one_error_line(capsys)
    assert "corrupt: " in line and f"the first at byte {at}" in line and "0xa9" in line and "--partial" in line, line
    assert not (tmp_path / "u.log").exists()
    assert fusion_import(tmp_path / "u.bin", "-o", tmp_path / "u.log", "--partial") == 0
    assert f"byte {at}" in capsys.readouterr().err
    rec = Recording(tmp_path / "u.log")
    t = 0.1 * np.arange(40) + 1.0
    np.testing.assert_allclose(rec.times("imu"), np.delete(t, 25), atol=1e-9)   # all but the damaged one
    np.testing.assert_allclose(rec.times("gps"), t, atol=1e-9)


def test_dataflash_absurd_instance_or_time_is_skipped_and_said(tmp_path, capsys):
    bad, at = _ap(mark=20)
    # instance 190 and a time of 4.7e12 s in one IMU message (a flip that left its header valid)
    bad[at + 3:at + 11] = (4_755_801_206_521_644_000).to_bytes(8, "little")
    bad[at + 11] = 190
    (tmp_path / "a.bin").write_bytes(bytes(bad))
    assert fusion_import(tmp_path / "a.bin", "-o", tmp_path / "a.log") == 0
    err = capsys.readouterr().err
    assert f"IMU: 1 message(s) with an absurd time or instance number skipped as corrupt: byte {at}" in err, err
    rec = Recording(tmp_path / "a.log")
    assert set(rec.t) == {"imu", "gps"}
    assert rec.times("imu").max() < 5.0 and len(rec.times("imu")) == 39


def test_dataflash_log_concatenated_with_itself_is_said_and_not_doubled(tmp_path, capsys):
    data, _ = _ap()
    (tmp_path / "one.bin").write_bytes(bytes(data))
    (tmp_path / "two.bin").write_bytes(bytes(data + data))
    assert fusion_import(tmp_path / "one.bin", "-o", tmp_path / "one.log") == 0
    capsys.readouterr()
    assert fusion_import(tmp_path / "two.bin", "-o", tmp_path / "two.log") == 0
    err = capsys.readouterr().err
    assert "clock goes back from 4.900 s to 1.000 s" in err and "IMU 40" in err, err
    one, two = Recording(tmp_path / "one.log"), Recording(tmp_path / "two.log")
    for s in ("imu", "gps"):
        np.testing.assert_array_equal(one.times(s), two.times(s))
        np.testing.assert_array_equal(one.values(s), two.values(s))


def test_header_values_are_one_printable_line():
    """A log's info string with NULs (PX4 sys_name 'PX4\\0\\0') made the recording a binary file to grep."""
    from fusion.api.importing import ImportedLog
    from fusion.importers.writer import render

    log = ImportedLog()
    log.meta["vehicle"] = "PX4\x00\x00 v1.14\nboard"
    head = "".join(render(log))
    assert "# vehicle: PX4 v1.14 board\n" in head and "\x00" not in head
