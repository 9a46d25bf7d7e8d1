"""``fusion import`` of ArduPilot DataFlash logs: small .bin files written here with the format's own FMT,
FMTU, UNIT and MULT records (dataflash_builder), so the expected values are the ones written, converted by
their definitions (mGauss -> uT, course and speed -> NED velocity, ZYX Euler -> quaternion by scipy).

Times here are the log's own stamps (sensor time, and the UTC start from the GPS week), compared with the
values written; nothing measures how long the code takes (speed is in benchmarks/)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from import_helpers import Recording, fusion_import, one_error_line
from dataflash_builder import DataflashWriter

import pymavlink  # noqa: E402,F401  a dependency: a missing one is a failure, not a skip

ORIGIN = (-35.3632621, 149.1652374, 584.07)


def _flight(n: int = 60, units: bool = True, gyro_units: str | None = None, seed: int = 3):
    """A 10 Hz log of n samples with two IMUs, GPS + GPA, MAG, BARO, ATT and two EKF3 cores. Returns the
    writer and the values written (in the log's units)."""
    rng = np.random.default_rng(seed)
    w = DataflashWriter(units=units)
    for name in ("ORGN", "IMU", "GPS", "MAG", "BARO", "ATT", "XKF1", "MSG"):
        w.declare(name)
    w.write("MSG", TimeUS=400_000, Message="ArduCopter V4.5.1 (1a2b3c4d)")
    if gyro_units:
        w.declare("IMU", units=gyro_units)   # a second FMT for IMU redeclares it (as a log may)
    w.write("ORGN", TimeUS=500_000, Type=0, Lat=ORIGIN[0], Lng=ORIGIN[1], Alt=ORIGIN[2])
    v = {k: [] for k in ("t", "acc", "gyr", "acc2", "lat", "lon", "alt", "spd", "crs", "vz", "status", "mag",
                         "press", "temp", "balt", "rpy", "pos", "vel")}
    for k in range(n):
        t = 2_000_000 + 100_000 * k
        acc = rng.normal([0, 0, -9.8], 0.2)
        gyr = rng.normal(0, 0.1, 3)
        acc2 = rng.normal([0, 0, -9.8], 0.2)
        w.write("IMU", TimeUS=t, I=0, **dict(zip(("AccX", "AccY", "AccZ", "GyrX", "GyrY", "GyrZ"), [*acc, *gyr])))
        w.write("IMU", TimeUS=t + 7, I=1, **dict(zip(("AccX", "AccY", "AccZ"), acc2)))
        lat, lon = ORIGIN[0] + 1e-6 * k, ORIGIN[1] + 2e-6 * k
        alt, spd, crs, vz = ORIGIN[2] + 0.01 * k, 1.0 + 0.1 * k, (37.0 * k) % 360, 0.3 - 0.01 * k
        status = 1 if k < 3 else 3
        w.write("GPS", TimeUS=t, I=0, Status=status, NSats=12, HDop=0.9, Lat=lat, Lng=lon, Alt=alt, Spd=spd,
                GCrs=crs, VZ=vz, GWk=2300, GMS=345_600_000 + 100 * k)
        mag = rng.integers(-600, 600, 3)                 # mGauss, int16 (multiplier 1e-3 to Gauss)
        w.write("MAG", TimeUS=t + 3, I=0, MagX=mag[0], MagY=mag[1], MagZ=mag[2])
        press, temp, balt = 95000 + 10.0 * k, 25.0 + 0.01 * k, 0.5 * k
        w.write("BARO", TimeUS=t + 5, I=0, Alt=balt, Press=press, Temp=temp)
        rpy = (5.0 * np.sin(k / 5), -3.0 + 0.1 * k, (20.0 * k) % 360)      # deg, 2 decimals in the log
        w.write("ATT", TimeUS=t, Roll=rpy[0], Pitch=rpy[1], Yaw=rpy[2])
        pos, vel = rng.normal(0, 10, 3), rng.normal(0, 2, 3)
        if k == 10:
            w.write("MSG", TimeUS=t, Message="EKF3 IMU0 is using GPS")
        for core, off in ((0, 0.0), (1, 100.0)):         # core 1 differs: only the lowest core is the reference
            w.write("XKF1", TimeUS=t, C=core, Roll=rpy[0], Pitch=rpy[1], Yaw=rpy[2],
                    **dict(zip(("PN", "PE", "PD", "VN", "VE", "VD"), [*(pos + off), *vel])))
        for key, val in (("t", t / 1e6), ("acc", acc), ("gyr", gyr), ("acc2", acc2), ("lat", lat), ("lon", lon),
                         ("alt", alt), ("spd", spd), ("crs", crs), ("vz", vz), ("status", status), ("mag", mag),
                         ("press", press), ("temp", temp), ("balt", balt), ("rpy", rpy), ("pos", pos), ("vel", vel)):
            v[key].append(val)
    return w, {k: np.array(x) for k, x in v.items()}


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    d = tmp_path_factory.mktemp("df")
    w, v = _flight()
    w.save(d / "flight.bin")
    assert fusion_import(d / "flight.bin", "-o", d / "flight.log") == 0
    return Recording(d / "flight.log"), v, d / "flight.bin"


def test_imu_instances_in_si(imported):
    rec, v, _ = imported
    np.testing.assert_allclose(rec.times("imu"), v["t"], atol=1e-9)
    np.testing.assert_allclose(rec.values("imu"), np.hstack([v["acc"], v["gyr"]]), rtol=1e-6, atol=1e-7)  # float32
    np.testing.assert_allclose(rec.times("imu2"), v["t"] + 7e-6, atol=1e-9)
    np.testing.assert_allclose(rec.values("imu2")[:, :3], v["acc2"], rtol=1e-6)


def test_gps_fix_filter_and_velocity_from_course(imported):
    rec, v, _ = imported
    ok = v["status"] >= 2
    np.testing.assert_allclose(rec.column("gps", "lat"), v["lat"][ok], atol=1e-9)
    np.testing.assert_allclose(rec.column("gps", "lon"), v["lon"][ok], atol=1e-9)
    np.testing.assert_allclose(rec.column("gps", "alt"), v["alt"][ok], atol=0.006)       # cm in the log
    spd, crs = v["spd"][ok], np.radians(v["crs"][ok])
    np.testing.assert_allclose(rec.column("gps", "vn"), spd * np.cos(crs), atol=1e-5)
    np.testing.assert_allclose(rec.column("gps", "ve"), spd * np.sin(crs), atol=1e-5)
    np.testing.assert_allclose(rec.column("gps", "vd"), v["vz"][ok], atol=1e-6)


def test_mag_milligauss_multiplier_to_microtesla(imported):
    rec, v, _ = imported
    np.testing.assert_allclose(rec.values("mag"), v["mag"] * 1e-3 * 100.0, rtol=1e-9)   # mGauss -> G -> uT


def test_baro(imported):
    rec, v, _ = imported
    np.testing.assert_allclose(rec.column("baro", "pressure"), v["press"], rtol=1e-7)
    np.testing.assert_allclose(rec.column("baro", "temp"), v["temp"], atol=0.006)       # cdegC in the log


def test_reference_from_lowest_ekf_core_with_att_quaternion(imported):
    rec, v, _ = imported
    assert rec.header.fields["reference"] == ("px", "py", "pz", "vx", "vy", "vz", "qw", "qx", "qy", "qz")
    val = rec.values("reference")
    # positions re-expressed about the recording's origin, the first accepted GPS fix (fix 3, 12 satellites:
    # the fourth sample), from the EKF's own origin (ORGN) by WGS84 (fusion.importers.flight)
    import pymap3d
    k = int(np.flatnonzero(v["status"] >= 3)[0])
    fix0 = (v["lat"][k], v["lon"][k], v["alt"][k])
    geo = pymap3d.ned2geodetic(*v["pos"].T, *ORIGIN)
    expected = np.column_stack(pymap3d.geodetic2ned(*geo, *fix0))
    np.testing.assert_allclose(val[:, :3], expected, rtol=1e-6, atol=1e-3)   # core 0, not core 1 (+100 m)
    np.testing.assert_allclose(val[:, 3:6], v["vel"], rtol=1e-6, atol=1e-6)
    rpy = np.round(v["rpy"], 2)   # the log holds centidegrees
    q = Rotation.from_euler("ZYX", np.radians(rpy[:, ::-1])).as_quat()[:, [3, 0, 1, 2]]   # body-to-NED, w first
    got = val[:, 6:]
    sign = np.sign(np.sum(q * got, axis=1))[:, None]
    np.testing.assert_allclose(got, q * sign, atol=1e-7)
    lat, lon, alt = map(float, rec.header.meta["origin"].split())
    assert (lat, lon) == pytest.approx(fix0[:2], abs=1e-9) and alt == pytest.approx(fix0[2], abs=0.006)
    frame = next(c for c in rec.comments if c.startswith("# reference frame:"))
    assert "ORGN" not in rec.header.meta["origin_source"] and "-35.3632621" in frame


def test_values_equal_what_pymavlink_reads(imported):
    from pymavlink.DFReader import DFReader_binary
    rec, _, path = imported
    r = DFReader_binary(str(path))
    acc = []
    while (m := r.recv_match(type="IMU")) is not None:
        if m.I == 0:
            acc.append([m.AccX, m.AccY, m.AccZ])
    np.testing.assert_allclose(rec.values("imu")[:, :3], acc, rtol=1e-7)


def test_attitude_interpolated_to_ekf_times(tmp_path):
    """A steady yaw rate: slerp is exact, so the reference between ATT samples is the mid-point yaw."""
    w = DataflashWriter()
    for name in ("ATT", "XKF1"):
        w.declare(name)
    for k in range(10):
        w.write("ATT", TimeUS=1_000_000 + 100_000 * k, Yaw=10.0 * k)
        w.write("XKF1", TimeUS=1_050_000 + 100_000 * k, C=0, PN=k)
    w.save(tmp_path / "a.bin")
    assert fusion_import(tmp_path / "a.bin", "-o", tmp_path / "a.log") == 0
    q = Recording(tmp_path / "a.log").values("reference")[:9, 6:]
    want = Rotation.from_euler("Z", np.radians(10.0 * np.arange(9) + 5.0)[:, None]).as_quat()[:, [3, 0, 1, 2]]
    np.testing.assert_allclose(np.abs(np.sum(q * want, axis=1)), 1.0, atol=1e-12)


def test_units_from_fmtu_convert_or_are_refused(tmp_path, capsys):
    w, v = _flight(n=5, gyro_units="s#kkkooo--O--zz")    # gyro declared in deg/s
    w.save(tmp_path / "d.bin")
    assert fusion_import(tmp_path / "d.bin", "-o", tmp_path / "d.log", "--sensors", "imu") == 0
    np.testing.assert_allclose(Recording(tmp_path / "d.log").values("imu")[:, 3:], np.radians(v["gyr"]), rtol=1e-6)
    capsys.readouterr()
    w, _ = _flight(n=5, gyro_units="s#mmmooo--O--zz")    # gyro "in metres": refused, named
    w.save(tmp_path / "m.bin")
    assert fusion_import(tmp_path / "m.bin", "-o", tmp_path / "m.log") == 2
    line = one_error_line(capsys)
    assert "IMU.GyrX" in line and "'m'" in line


def test_log_without_fmtu_uses_the_documented_layout(tmp_path):
    w, v = _flight(n=5, units=False)
    w.save(tmp_path / "old.bin")
    assert fusion_import(tmp_path / "old.bin", "-o", tmp_path / "old.log", "--sensors", "mag") == 0
    np.testing.assert_allclose(Recording(tmp_path / "old.log").values("mag"), v["mag"] * 0.1, rtol=1e-9)


def test_time_slice_and_instance_selection(tmp_path):
    w, v = _flight()
    w.save(tmp_path / "f.bin")
    assert fusion_import(tmp_path / "f.bin", "-o", tmp_path / "s.log", "--start", "3", "--end", "5.5",
                         "--sensors", "imu2", "mag") == 0
    rec = Recording(tmp_path / "s.log")
    assert set(rec.t) == {"imu2", "mag"}
    t = v["t"] + 7e-6
    np.testing.assert_allclose(rec.times("imu2"), t[(t >= 3) & (t <= 5.5)], atol=1e-9)


def test_truncated_corrupt_and_foreign_files_are_one_error(tmp_path, capsys):
    w, _ = _flight(n=20)
    data = bytes(w.buf)
    (tmp_path / "cut.bin").write_bytes(data[:-11])
    assert fusion_import(tmp_path / "cut.bin", "-o", tmp_path / "c.log") == 2
    line = one_error_line(capsys)
    assert "truncated" in line and "cut.bin" in line
    assert fusion_import(tmp_path / "cut.bin", "-o", tmp_path / "c.log", "--partial") == 0
    assert len(Recording(tmp_path / "c.log").times("imu")) >= 19
    capsys.readouterr()
    bad = bytearray(data)
    mid = len(bad) // 2
    bad[mid:mid + 40] = b"\x00" * 40
    (tmp_path / "bad.bin").write_bytes(bytes(bad))
    assert fusion_import(tmp_path / "bad.bin", "-o", tmp_path / "b.log") == 2
    assert "corrupt" in one_error_line(capsys)
    for name, content in (("text.bin", b"QGC WPL 110\n0\t1\t0\n"), ("empty.bin", b""), ("fmt.bin", data[:89])):
        (tmp_path / name).write_bytes(content)
        assert fusion_import(tmp_path / name, "-o", tmp_path / "x.log") == 2
        assert name in one_error_line(capsys)


def test_start_utc_from_gps_week_and_milliseconds(imported):
    import datetime as dt
    rec, v, _ = imported
    # The log's first GPS row (log time t = 2.0 s) says week 2300, 345600 s; GPS - UTC = 18 s since 2017.
    # The same instant by Unix-epoch arithmetic (GPS epoch 1980-01-06 = Unix 315964800), a second method:
    unix = 315_964_800 + 2300 * 604_800 + 345_600 - 18 - 2
    want = dt.datetime.fromtimestamp(unix, dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
    assert rec.header.meta["start_utc"] == want      # a date in the log's data, compared as text


def test_vehicle_and_text_messages_in_the_header(imported):
    rec, v, _ = imported
    assert rec.header.meta["vehicle"] == "ArduCopter V4.5.1 (1a2b3c4d)"
    assert f"# message {v['t'][10]:.3f}: EKF3 IMU0 is using GPS" in rec.comments


def test_earth_field_from_att(imported):
    rec, v, _ = imported
    rpy = np.round(v["rpy"], 2)
    rot = Rotation.from_euler("ZYX", np.radians(rpy[:, ::-1]))
    want = np.mean(rot.apply(v["mag"] * 0.1), axis=0)   # mGauss -> uT, rotated to NED (MAG 3 us after ATT)
    line = next(c for c in rec.comments if c.startswith("# mag earth_field_ned:"))
    np.testing.assert_allclose([float(x) for x in line.split(":")[1].split()], want, atol=5e-3)


def test_a_missing_gpa_record_costs_only_its_own_fix(tmp_path, capsys):
    """One GPS sample without its GPA (a logger that dropped the record) does not remove the receiver
    accuracies of the whole log: each fix has its own GPA's, a missing one the previous
    GPA's (within 1.5 s), and none within 1.5 s is 0: unknown (the gps measurement's floor)."""
    w = DataflashWriter()
    for name in ("IMU", "GPS"):
        w.declare(name)
    w.declare("GPA", "QBCCCCfBIH", "TimeUS,I,VDop,HAcc,VAcc,SAcc,YAcc,VV,SMS,Delta")
    hacc = 1.0 + 0.1 * np.arange(40)
    for k in range(40):
        t = 1_000_000 + 200_000 * k
        w.write("IMU", TimeUS=t, I=0, AccZ=-9.8)
        w.write("GPS", TimeUS=t, I=0, Status=3, NSats=12, HDop=0.9, Lat=ORIGIN[0], Lng=ORIGIN[1], Alt=ORIGIN[2])
        if k != 7 and not 20 <= k < 30:                   # one record dropped, then 2 s of them
            w.write("GPA", TimeUS=t, I=0, HAcc=hacc[k], VAcc=2 * hacc[k])
    w.save(tmp_path / "gpa.bin")
    assert fusion_import(tmp_path / "gpa.bin", "-o", tmp_path / "gpa.log") == 0
    err = capsys.readouterr().err
    rec = Recording(tmp_path / "gpa.log")
    want = hacc.copy()
    want[7] = hacc[6]                                     # the previous GPA, 0.2 s earlier
    want[20:27] = hacc[19]                                # within 1.5 s of the last one
    want[27:30] = 0.0                                     # none within 1.5 s: unknown
    np.testing.assert_allclose(rec.column("gps", "hacc"), want, rtol=1e-6)
    np.testing.assert_allclose(rec.column("gps", "vacc"), 2 * want, rtol=1e-6)
    assert "8 sample(s) without their GPA record" in err and "3 sample(s) without a GPA record within" in err


def test_two_d_fixes_are_not_exported_as_nmea(tmp_path, capsys):
    """A GGA cannot say that a height is unsolved: 2-D fixes (Status 2) written as NMEA would reach the nmea
    decoder as ordinary fixes, one of them its origin at the unsolved altitude. They are left
    out, with a note, as the numeric route's min_fix 3 leaves them out."""
    import pynmea2

    w = DataflashWriter()
    for name in ("IMU", "GPS"):
        w.declare(name)
    for k in range(20):
        t = 1_000_000 + 200_000 * k
        w.write("IMU", TimeUS=t, I=0, AccZ=-9.8)
        w.write("GPS", TimeUS=t, I=0, Status=2 if k < 5 else 3, NSats=5 if k < 5 else 12, HDop=2.5,
                Lat=ORIGIN[0], Lng=ORIGIN[1], Alt=0.0 if k < 5 else ORIGIN[2])
    w.save(tmp_path / "f.bin")
    assert fusion_import(tmp_path / "f.bin", "-o", tmp_path / "f.log", "--gps", "nmea") == 0
    assert "5 fix(es) not 3-D or better left out (5 of type 2" in capsys.readouterr().err
    ggas = [pynmea2.parse(r[0]) for r in Recording(tmp_path / "f.log").rows["gps"] if r[0].startswith("$GPGGA")]
    assert len(ggas) == 15 and all(abs(float(g.altitude) - ORIGIN[2]) < 1e-3 for g in ggas)


def test_an_extrapolated_fix_is_never_the_header_origin():
    """Fix types are codes: PX4's 8 (extrapolated) passed 'fix >= 3' and could become the origin."""
    from fusion.api import Stream
    from fusion.importers.flight import gps_origin
    from fusion.importers.gps_decoder import LAYOUTS

    fields = LAYOUTS[12]
    row = dict(zip(fields, [0.0] * len(fields)))

    def fix(t, ftype, lat):
        return [{**row, "lat": lat, "lon": 8.5, "alt": 400.0, "fix": ftype, "nsat": 12}[f] for f in fields]

    gps = Stream("gps", tuple(fields), np.array([1.0, 2.0, 3.0]),
                 np.array([fix(1.0, 8, 47.0), fix(2.0, 7, 47.1), fix(3.0, 3, 47.2)]))
    assert gps_origin(gps) == (3.0, 47.2, 8.5, 400.0)
