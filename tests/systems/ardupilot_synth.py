"""A synthetic ArduPilot DataFlash log with known truth, for the ArduPilot config's end-to-end test and
``experiments/real_logs.py``: the project's simulator (fusion.simulate) flies a vehicle with an IMU, a GPS
and a magnetometer, and its recording is written as a ``.bin`` with the format's own FMT/FMTU/UNIT/MULT
records (tests/importers/dataflash_builder.py), as ArduPilot's AP_Logger lays them out: IMU, GPS + GPA, MAG,
ORGN, and as the "onboard EKF" (XKF1 + ATT) the simulator's truth, so the agreement `fusion run` reports on
this log is the config's error against the truth.

Sensor figures: an ICM-20689-class IMU (gyro 0.015 deg/s/sqrt(Hz) = 2.6e-4 rad/s/sqrt(Hz), accelerometer
145 ug/sqrt(Hz) = 1.4e-3 m/s^2/sqrt(Hz)), logged at 100 Hz; a u-blox M8-class GPS at 5 Hz (0.7 m / 1.2 m,
0.1 m/s, its accuracies logged in GPA); a magnetometer at 10 Hz (0.3 uT). The field: WMM-2020 at ArduPilot's
SITL home (CMAC, -35.363 149.165): declination 12.3 deg, inclination -65.8 deg, 57.6 uT (approximate).
The vehicle is moving from the first sample (no static period)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "importers"))
from dataflash_builder import DataflashWriter  # noqa: E402

ORIGIN = (-35.363262, 149.165237, 584.0)
FIELD = {"declination_deg": 12.3, "inclination_deg": -65.8, "intensity": 57.6}
GPS_SD = {"horizontal_sd": 0.7, "vertical_sd": 1.2, "velocity_sd": 0.1}
#: s a fix is logged after the instant it measures: ArduPilot's default GPS lag (GPS_DELAY_MS 0: the
#: driver's, 0.2 s; the configs model it with time_offset), as a receiver's solution reaches the autopilot
GPS_LAG = 0.2

SCENARIO = {
    "name": "ardupilot_synthetic",
    "seed": 11,
    "dim": 3,
    "origin": {"lat_deg": ORIGIN[0], "lon_deg": ORIGIN[1], "alt_m": ORIGIN[2]},
    "start_utc": "2024-05-01T02:00:00",
    "trajectory": {"type": "waypoints", "speed": 8.0, "max_accel": 2.0, "radius": 15.0,
                   "waypoints": [[0.0, 0.0, -30.0], [150.0, 0.0, -35.0], [150.0, 120.0, -35.0],
                                 [0.0, 120.0, -30.0], [0.0, 20.0, -30.0]]},
    "duration": 40.0,
    "sensors": {
        "imu": {"type": "imu", "rate_hz": 100, "accel_noise_density": 1.4e-3, "gyro_noise_density": 2.6e-4,
                "accel_bias_sd": 0.05, "gyro_bias_sd": 0.003, "accel_bias_rw": 1.0e-4, "gyro_bias_rw": 1.0e-5},
        "gps": {"type": "gps", "rate_hz": 5, **GPS_SD, "satellites": 14, "hdop": 0.8},
        "mag": {"type": "magnetometer", "rate_hz": 10, **FIELD, "noise_sd": 0.3},
    },
}


def simulate(seed: int = 11) -> str:
    """The simulator's recording (log text with truth) of SCENARIO."""
    from fusion.simulate.engine import simulate as run
    from fusion.simulate.scenario import load_scenario
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "ardupilot_synthetic.yaml"
        path.write_text(yaml.safe_dump(SCENARIO), encoding="utf-8")
        sc, text = load_scenario(str(path))
        return run(sc, seed=seed, where=str(path), text=text)


def _records(text: str) -> dict[str, list[tuple[float, list[str]]]]:
    out: dict[str, list[tuple[float, list[str]]]] = {}
    for line in text.splitlines():
        if line.startswith("#") or not line:
            continue
        t, sensor, *values = line.split("*")[0].split(",") if "$" in line else line.split(",")
        out.setdefault(sensor, []).append((float(t), values))
    return out


def _euler_deg(q: np.ndarray) -> np.ndarray:
    from fusion.quaternion import to_euler
    return np.degrees(to_euler(q))


def write_bin(path: str | Path, seed: int = 11) -> dict[str, np.ndarray]:
    """Simulate and write the ``.bin``; returns the truth (t, p, v, q) for the test's own checks."""
    import pynmea2

    rec = _records(simulate(seed))
    truth = np.array([[t, *map(float, v[:10])] for t, v in rec["truth"]])
    w = DataflashWriter()
    for name in ("ORGN", "IMU", "GPS", "MAG", "ATT", "XKF1", "MSG"):
        w.declare(name)
    w.declare("GPA", "QBCCCCfBIH", "TimeUS,I,VDop,HAcc,VAcc,SAcc,YAcc,VV,SMS,Delta", units="s#mmmnd-s-",
              mults="F-BBBB0-C-")
    us = lambda t: int(round(1e6 * (t + 1.0)))   # noqa: E731  boot clock: the log starts 1 s after boot
    w.write("MSG", TimeUS=us(0.0), Message="ArduCopter V4.5.7 (synthetic: fusion.simulate)")
    w.write("ORGN", TimeUS=us(0.0), Type=0, Lat=ORIGIN[0], Lng=ORIGIN[1], Alt=ORIGIN[2])
    events = []
    for t, v in rec["imu"]:
        ax, ay, az, gx, gy, gz = map(float, v)
        events.append((t, 0, "IMU", dict(I=0, AccX=ax, AccY=ay, AccZ=az, GyrX=gx, GyrY=gy, GyrZ=gz)))
    for t, v in rec["mag"]:
        m = np.round(np.array(v, float) * 10.0)            # uT -> mGauss (int16, multiplier 1e-3 to G)
        events.append((t, 2, "MAG", dict(I=0, MagX=m[0], MagY=m[1], MagZ=m[2])))
    gga = {}
    for t, v in rec["gps"]:
        s = pynmea2.parse(",".join(v) if not v[0].startswith("$") else ",".join(v).split("*")[0], check=False)
        gga.setdefault(t, {})[s.sentence_type] = s
    for t, s in sorted(gga.items()):
        g, r = s.get("GGA"), s.get("RMC")
        if g is None or r is None:
            continue
        vz = float(np.interp(t, truth[:, 0], truth[:, 6]))
        events.append((t + GPS_LAG, 1, "GPS", dict(I=0, Status=3, NSats=int(g.num_sats), HDop=float(g.horizontal_dil),
                                         Lat=g.latitude, Lng=g.longitude, Alt=float(g.altitude),
                                         Spd=float(r.spd_over_grnd) * 1852.0 / 3600.0,
                                         GCrs=float(r.true_course or 0.0), VZ=vz, GWk=2312, GMS=0)))
        events.append((t + GPS_LAG, 1, "GPA", dict(I=0, VDop=1.2, HAcc=GPS_SD["horizontal_sd"], VAcc=GPS_SD["vertical_sd"],
                                         SAcc=GPS_SD["velocity_sd"])))
    for row in truth[::10]:                                 # the "EKF" at 10 Hz: the truth
        t, p, vel, q = row[0], row[1:4], row[4:7], row[7:11]
        rpy = _euler_deg(q)
        events.append((t, 3, "ATT", dict(Roll=rpy[0], Pitch=rpy[1], Yaw=rpy[2] % 360.0)))
        events.append((t, 3, "XKF1", dict(C=0, Roll=rpy[0], Pitch=rpy[1], Yaw=rpy[2] % 360.0,
                                          **dict(zip(("PN", "PE", "PD", "VN", "VE", "VD"), [*p, *vel])))))
    for t, _, name, values in sorted(events, key=lambda e: (e[0], e[1])):
        w.write(name, TimeUS=us(t), **values)
    w.save(path)
    return {"t": truth[:, 0] + 1.0, "p": truth[:, 1:4], "v": truth[:, 4:7], "q": truth[:, 7:11]}


def import_as_recording(bin_path: str | Path, out: str | Path) -> None:
    """``fusion import`` of the synthetic .bin to ``out``, its source line naming this generator (the
    shipped recordings/flight_synthetic.log, the real-vehicle configs' own recording, is exactly this)."""
    import contextlib
    import io

    from fusion.cli import main

    bin_path, out = Path(bin_path), Path(out)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["import", str(bin_path), "-o", str(out), "--force"]) == 0
    text = out.read_text(encoding="utf-8").replace(f"# source: {bin_path.name} ",
                                                   "# source: tests/systems/ardupilot_synth.py ")
    out.write_text(text, encoding="utf-8")


if __name__ == "__main__":
    out = sys.argv[1] if len(sys.argv) > 1 else "ardupilot_synthetic.bin"
    write_bin(out)
    print(f"wrote {out}")
