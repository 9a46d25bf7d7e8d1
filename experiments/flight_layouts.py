"""Synthetic flight logs of each layout the importers read, all from one simulated flight (the project's
simulator, tests/systems/ardupilot_synth.py's scenario: an IMU at 100 Hz, GPS at 5 Hz, magnetometer at
10 Hz, moving from the first sample), for experiments/real_flights.py. The "onboard estimator" of each log
is the simulator's truth, so the agreement a run reports on them is its error.

- ``dataflash_new``: ArduPilot 4.x (``TimeUS``, GPS ``GMS``/``GWk``, GPA, FMTU units, XKF1 + ATT, ORGN, EV/MODE);
- ``dataflash_old``: Copter 3.3 (no FMTU; GPS ``Status,TimeMS,Week,...,T``: ``TimeMS`` GPS time of week,
  ``T`` the boot clock; EKF1 + ATT, no ORGN; the log boots 11.46 s before the flight);
- ``ulog_new``: PX4 1.14-like topics (``sensor_combined`` with ``gyro_integral_dt``, float ``sensor_gps``,
  ``vehicle_magnetometer``, ``vehicle_local_position`` + ``vehicle_attitude``, ``vehicle_status``);
- ``ulog_old``: PX4 1.5-like (``sensor_combined`` with ``magnetometer_ga`` and ``baro_alt_meter`` inside,
  integer ``vehicle_gps_position``);
- ``ulog_low_rate``: ``ulog_new`` logged at 10 Hz, each row 4 ms of gyro integral (a log of too low a rate).
"""
from __future__ import annotations

import datetime as dt
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "systems"))
sys.path.insert(0, str(ROOT / "tests" / "importers"))

from ardupilot_synth import GPS_SD, ORIGIN, SCENARIO, _euler_deg, _records, simulate  # noqa: E402
from dataflash_builder import DataflashWriter  # noqa: E402
from ulog_builder import UlogWriter  # noqa: E402

LAYOUTS = ("dataflash_new", "dataflash_old", "ulog_new", "ulog_old", "ulog_low_rate")
#: s from the instant a fix measures to its log stamp: the autopilots' default GPS lag (ArduPilot's driver
#: 0.2 s, PX4 EKF2_GPS_DELAY 0.11 s), which the vehicle configs' time_offset models
GPS_LAG = {"dataflash": 0.2, "ulog": 0.11}
KNOT = 1852.0 / 3600.0


def flight(seed: int = 11) -> dict:
    """The simulated flight as arrays: imu (t, 6), gps (t, lat, lon, alt, vn, ve, vd, nsat, hdop), mag (t, 3 uT),
    truth (t, p, v, q)."""
    import pynmea2

    rec = _records(simulate(seed))
    truth = np.array([[t, *map(float, v[:10])] for t, v in rec["truth"]])
    imu = np.array([[t, *map(float, v)] for t, v in rec["imu"]])
    mag = np.array([[t, *map(float, v)] for t, v in rec["mag"]])
    by_t: dict[float, dict] = {}
    for t, v in rec["gps"]:
        s = pynmea2.parse(",".join(v).split("*")[0], check=False)
        by_t.setdefault(t, {})[s.sentence_type] = s
    gps = []
    for t, s in sorted(by_t.items()):
        g, r = s.get("GGA"), s.get("RMC")
        if g is None or r is None:
            continue
        spd, crs = float(r.spd_over_grnd) * KNOT, np.radians(float(r.true_course or 0.0))
        vd = float(np.interp(t, truth[:, 0], truth[:, 6]))
        gps.append([t, g.latitude, g.longitude, float(g.altitude), spd * np.cos(crs), spd * np.sin(crs), vd,
                    int(g.num_sats), float(g.horizontal_dil)])
    return {"imu": imu, "gps": np.array(gps), "mag": mag, "truth": truth}


def _gps_time(t: float) -> tuple[int, int]:
    """(GPS week, time of week ms) of flight time ``t`` s (the scenario's start_utc; GPS - UTC = 18 s)."""
    start = dt.datetime.fromisoformat(SCENARIO["start_utc"]).replace(tzinfo=dt.timezone.utc)
    gps = start + dt.timedelta(seconds=t + 18) - dt.datetime(1980, 1, 6, tzinfo=dt.timezone.utc)
    total_ms = int(round(gps.total_seconds() * 1000))
    return total_ms // 604_800_000, total_ms % 604_800_000


def write(layout: str, f: dict, path: Path) -> None:
    """Write the flight ``f`` (from :func:`flight`) as ``layout`` to ``path``."""
    {"dataflash_new": _dataflash_new, "dataflash_old": _dataflash_old, "ulog_new": _ulog_new,
     "ulog_old": _ulog_old, "ulog_low_rate": _ulog_low_rate}[layout](f, path)


def _ekf_rows(f: dict):
    for row in f["truth"][::10]:                                   # the "EKF" at 10 Hz: the truth
        yield row[0], row[1:4], row[4:7], row[7:11], _euler_deg(row[7:11])


def _dataflash(f: dict, path: Path, old: bool) -> None:
    boot = 11.46 if old else 1.0                                  # s from boot to the flight's start
    w = DataflashWriter(units=not old)
    if old:
        w.declare("IMU", "QffffffIIfBB", "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,ErrG,ErrA,Temp,GyHlt,AcHlt")
        w.declare("GPS", "BIHBcLLeeEefI", "Status,TimeMS,Week,NSats,HDop,Lat,Lng,RelAlt,Alt,Spd,GCrs,VZ,T")
        w.declare("MAG", "Qhhhhhhhhh", "TimeUS,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOfsX,MOfsY,MOfsZ")
        w.declare("ATT", "QccccCCCC", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw")
        w.declare("EKF1", "QccCffffffccc", "TimeUS,Roll,Pitch,Yaw,VN,VE,VD,PN,PE,PD,GX,GY,GZ")
    else:
        for name in ("ORGN", "IMU", "GPS", "MAG", "ATT", "XKF1"):
            w.declare(name)
        w.declare("GPA", "QBCCCCfBIH", "TimeUS,I,VDop,HAcc,VAcc,SAcc,YAcc,VV,SMS,Delta", units="s#mmmnd-s-",
                  mults="F-BBBB0-C-")
    w.declare("EV", "QB", "TimeUS,Id")
    w.declare("MODE", "QMB", "TimeUS,Mode,ModeNum")
    us = lambda t: int(round(1e6 * (t + boot)))   # noqa: E731
    if not old:
        w.write("ORGN", TimeUS=us(0.0), Type=0, Lat=ORIGIN[0], Lng=ORIGIN[1], Alt=ORIGIN[2])
    t_end = float(f["imu"][-1, 0])
    ev = [(0.0, -1, "MODE", dict(TimeUS=us(0.0), Mode=5, ModeNum=5)), (0.0, -1, "EV", dict(TimeUS=us(0.0), Id=10)),
          (t_end - 0.5, 9, "EV", dict(TimeUS=us(t_end - 0.5), Id=11))]
    for t, ax, ay, az, gx, gy, gz in f["imu"].tolist():
        ev.append((t, 0, "IMU", dict(TimeUS=us(t), I=0, AccX=ax, AccY=ay, AccZ=az, GyrX=gx, GyrY=gy, GyrZ=gz)))
    for t, *m in f["mag"].tolist():
        m = np.round(np.array(m) * 10.0)                           # uT -> mGauss
        ev.append((t, 2, "MAG", dict(TimeUS=us(t), I=0, MagX=m[0], MagY=m[1], MagZ=m[2])))
    for t, lat, lon, alt, vn, ve, vd, nsat, hdop in f["gps"].tolist():
        spd, crs = float(np.hypot(vn, ve)), float(np.degrees(np.arctan2(ve, vn)) % 360.0)
        wk, tow = _gps_time(t)                                     # the instant measured ...
        t = t + GPS_LAG["dataflash"]                               # ... logged later
        common = dict(Status=3, NSats=int(nsat), HDop=hdop, Lat=lat, Lng=lon, Alt=alt, Spd=spd, GCrs=crs, VZ=vd)
        if old:
            ev.append((t, 1, "GPS", dict(TimeMS=tow, Week=wk, RelAlt=alt - ORIGIN[2], T=us(t) // 1000, **common)))
        else:
            ev.append((t, 1, "GPS", dict(TimeUS=us(t), I=0, GMS=tow, GWk=wk, **common)))
            ev.append((t, 1, "GPA", dict(TimeUS=us(t), I=0, VDop=1.2, HAcc=GPS_SD["horizontal_sd"],
                                         VAcc=GPS_SD["vertical_sd"], SAcc=GPS_SD["velocity_sd"])))
    for t, p, v, _, rpy in _ekf_rows(f):
        ev.append((t, 3, "ATT", dict(TimeUS=us(t), Roll=rpy[0], Pitch=rpy[1], Yaw=rpy[2] % 360.0)))
        ekf = dict(TimeUS=us(t), Roll=rpy[0], Pitch=rpy[1], Yaw=rpy[2] % 360.0,
                   **dict(zip(("PN", "PE", "PD", "VN", "VE", "VD"), [*p, *v])))
        ev.append((t, 3, "EKF1", ekf) if old else (t, 3, "XKF1", dict(C=0, **ekf)))
    for _, _, name, values in sorted(ev, key=lambda e: (e[0], e[1])):
        w.write(name, **values)
    w.save(path)


def _dataflash_new(f, path):
    _dataflash(f, path, old=False)


def _dataflash_old(f, path):
    _dataflash(f, path, old=True)


def _ulog(f: dict, path: Path, old: bool, every: int = 1, integral_us: int = 10_000) -> None:
    t0_us = 5_000_000
    us = lambda t: int(round(1e6 * t)) + t0_us   # noqa: E731
    w = UlogWriter(start_us=t0_us)
    w.info("sys_name", "PX4")
    comb = [("float[3]", "gyro_rad"), ("uint32_t", "gyro_integral_dt"), ("int32_t", "accelerometer_timestamp_relative"),
            ("float[3]", "accelerometer_m_s2"), ("uint32_t", "accelerometer_integral_dt")]
    if old:
        comb += [("int32_t", "magnetometer_timestamp_relative"), ("float[3]", "magnetometer_ga"),
                 ("int32_t", "baro_timestamp_relative"), ("float", "baro_alt_meter"), ("float", "baro_temp_celcius")]
    w.topic("sensor_combined", comb)
    if old:
        w.topic("vehicle_gps_position", [("int32_t", "lat"), ("int32_t", "lon"), ("int32_t", "alt"),
                                         ("float", "eph"), ("float", "epv"), ("float", "hdop"), ("float", "vel_n_m_s"),
                                         ("float", "vel_e_m_s"), ("float", "vel_d_m_s"), ("bool", "vel_ned_valid"),
                                         ("uint8_t", "fix_type"), ("uint8_t", "satellites_used")])
    else:
        w.topic("sensor_gps", [("uint64_t", "time_utc_usec"), ("double", "latitude_deg"), ("double", "longitude_deg"),
                               ("double", "altitude_msl_m"), ("float", "eph"), ("float", "epv"), ("float", "hdop"),
                               ("float", "vel_n_m_s"), ("float", "vel_e_m_s"), ("float", "vel_d_m_s"),
                               ("bool", "vel_ned_valid"), ("uint8_t", "fix_type"), ("uint8_t", "satellites_used")])
        w.topic("vehicle_magnetometer", [("float[3]", "magnetometer_ga")])
    w.topic("vehicle_attitude", [("float[4]", "q")])
    w.topic("vehicle_local_position", [("bool", "xy_valid"), ("bool", "z_valid"), ("bool", "v_xy_valid"),
                                       ("bool", "v_z_valid"), ("float", "x"), ("float", "y"), ("float", "z"),
                                       ("float", "vx"), ("float", "vy"), ("float", "vz"), ("bool", "xy_global"),
                                       ("bool", "z_global"), ("double", "ref_lat"), ("double", "ref_lon"),
                                       ("float", "ref_alt")])
    w.topic("vehicle_status", [("uint8_t", "nav_state"), ("uint8_t", "arming_state"), ("bool", "failsafe")])
    gps_topic = "vehicle_gps_position" if old else "sensor_gps"
    for name in ("sensor_combined", gps_topic, "vehicle_attitude", "vehicle_local_position", "vehicle_status") + \
            (() if old else ("vehicle_magnetometer",)):
        w.subscribe(name)
    t_end = float(f["imu"][-1, 0])
    ev = [(0.0, "vehicle_status", dict(timestamp=us(0.0), nav_state=2, arming_state=2)),
          (t_end - 0.5, "vehicle_status", dict(timestamp=us(t_end - 0.5), nav_state=2, arming_state=1))]
    mag = f["mag"]
    for k, (t, ax, ay, az, gx, gy, gz) in enumerate(f["imu"].tolist()):
        if k % every:
            continue
        row = dict(timestamp=us(t), gyro_rad=[gx, gy, gz], gyro_integral_dt=integral_us,
                   accelerometer_m_s2=[ax, ay, az], accelerometer_integral_dt=integral_us)
        if old:
            j = int(np.searchsorted(mag[:, 0], t + 1e-9)) - 1
            if j >= 0:
                row.update(magnetometer_timestamp_relative=us(mag[j, 0]) - us(t),
                           magnetometer_ga=(mag[j, 1:] / 100.0).tolist())
            else:
                row.update(magnetometer_timestamp_relative=0x7FFFFFFF)
            row.update(baro_timestamp_relative=0, baro_alt_meter=float(ORIGIN[2] - np.interp(t, f["truth"][:, 0],
                                                                                             f["truth"][:, 3])),
                       baro_temp_celcius=20.0)
        ev.append((t, "sensor_combined", row))
    if not old:
        for t, *m in mag.tolist():
            ev.append((t, "vehicle_magnetometer", dict(timestamp=us(t), magnetometer_ga=[x / 100.0 for x in m])))
    start = dt.datetime.fromisoformat(SCENARIO["start_utc"]).replace(tzinfo=dt.timezone.utc).timestamp()
    for t, lat, lon, alt, vn, ve, vd, nsat, hdop in f["gps"].tolist():
        utc = int((start + t) * 1e6)                               # the instant measured, logged later
        t = t + GPS_LAG["ulog"]
        common = dict(timestamp=us(t), eph=GPS_SD["horizontal_sd"], epv=GPS_SD["vertical_sd"], vel_n_m_s=vn,
                      vel_e_m_s=ve, vel_d_m_s=vd, vel_ned_valid=True, fix_type=3, satellites_used=int(nsat))
        if old:
            ev.append((t, gps_topic, dict(lat=int(round(lat * 1e7)), lon=int(round(lon * 1e7)),
                                          alt=int(round(alt * 1e3)), hdop=hdop, **common)))
        else:
            ev.append((t, gps_topic, dict(time_utc_usec=utc, latitude_deg=lat, longitude_deg=lon,
                                          altitude_msl_m=alt, hdop=hdop, **common)))
    for t, p, v, q, _ in _ekf_rows(f):
        ev.append((t, "vehicle_attitude", dict(timestamp=us(t), q=list(q))))
        ev.append((t, "vehicle_local_position", dict(timestamp=us(t), xy_valid=True, z_valid=True, v_xy_valid=True,
                                                     v_z_valid=True, x=p[0], y=p[1], z=p[2], vx=v[0], vy=v[1],
                                                     vz=v[2], xy_global=True, z_global=True, ref_lat=ORIGIN[0],
                                                     ref_lon=ORIGIN[1], ref_alt=ORIGIN[2])))
    for _, name, values in sorted(ev, key=lambda e: e[0]):
        w.data(name, **values)
    w.save(path)


def _ulog_new(f, path):
    _ulog(f, path, old=False)


def _ulog_old(f, path):
    _ulog(f, path, old=True)


def _ulog_low_rate(f, path):
    _ulog(f, path, old=False, every=10, integral_us=4_000)
