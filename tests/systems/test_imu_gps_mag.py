"""End to end: configs/imu_gps_mag_ekf.yaml (paper 002) on recordings/car_gps_mag.log, through the CLI.

Bounds come from the sensors, not from a previous run: the fused position must beat the raw GPS fix
(scenario: 2 m horizontal, 3 m vertical sd, i.e. 4.1 m 3-D rms), the velocity its 0.1 m/s-per-axis
velocity over the run, the attitude a magnetometer-aided few degrees; the one lost fix of the scenario is
counted as rejected and nothing is malformed.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from fusion.cli import main

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "imu_gps_mag_ekf.yaml"
RAW_GPS_RMS = math.sqrt(2.0**2 + 2.0**2 + 3.0**2)     # m: scenarios/car_gps_mag.yaml


def run(tmp_path, *extra):
    out = tmp_path / f"s{len(list(tmp_path.iterdir()))}.json"
    assert main(["run", str(CONFIG), "-q", "--summary-json", str(out), *extra]) == 0
    return json.loads(out.read_text())


@pytest.fixture(scope="module")
def ekf(tmp_path_factory):
    return run(tmp_path_factory.mktemp("ekf"))


def test_config_validates():
    assert main(["validate", str(CONFIG)]) == 0


def test_ekf_run_against_truth(ekf):
    assert ekf["filter"] == "ekf"
    e = ekf["errors"]
    assert e["position_rmse_m"] < RAW_GPS_RMS / 2
    assert e["velocity_rmse_mps"] < 0.5
    assert e["attitude_rmse_deg"] < 2.0 and e["attitude_max_deg"] < 5.0
    el = e["element_rmse"]
    for name in ("bax", "bwz", "sax", "swz"):            # biases and scale factors compared with truth
        assert name in el
    assert el["bwz"] < 2e-3                               # rad/s: well under the 0.5 deg/s turn-on sd
    gps = ekf["sensors"]["gps"]
    assert gps["rejected"] == 1 and gps["malformed"] == 0   # the single lost fix (quality 0, status V)
    assert ekf["sensors"]["imu"]["used"] == ekf["sensors"]["imu"]["received"]
    c = ekf["consistency"]
    assert c["nees_dof"] == 21 and c["nees_mean"] < 21 * 1.5   # not overconfident


def test_srukf_runs_the_same_system(tmp_path, ekf):
    s = run(tmp_path, "--filter", "srukf", "--filter-param", "alpha=0.5")
    assert s["filter"] == "srukf"
    assert s["errors"]["position_rmse_m"] < RAW_GPS_RMS / 2
    assert abs(s["errors"]["attitude_rmse_deg"] - ekf["errors"]["attitude_rmse_deg"]) < 0.5


def test_bad_nmea_lines_are_counted_not_fatal(tmp_path):
    lines = (ROOT / "recordings" / "car_gps_mag.log").read_text().splitlines()
    bad = []
    n_broken = 0
    for line in lines:
        if ",gps,$GPRMC" in line and n_broken < 3 and float(line.split(",")[0]) > 45:
            line = line[:-2] + ("00" if line[-2:] != "00" else "01")   # wrong checksum
            n_broken += 1
        bad.append(line)
        if len(bad) > 8000:
            break
    log = tmp_path / "bad.log"
    log.write_text("\n".join(bad) + "\n")
    s = run(tmp_path, "--input", str(log))
    gps = s["sensors"]["gps"]
    assert gps["malformed"] == 3


def test_a_gps_stream_starting_after_the_imu_still_starts_the_filter_on_the_car(tmp_path):
    """With the GPS sentences starting TTFF s after the IMU, the origin window (origin_s of GPS messages)
    would run into the drive and start the filter at the origin at rest while the car moved (4 m/s, sd
    0.05), diverging to km. The first moving fix ends the window and starts the filter."""
    lines = (ROOT / "recordings" / "car_gps_mag.log").read_text().splitlines()
    for ttff in (5.0, 30.0):
        keep = [ln for ln in lines if ln.startswith("#") or ",gps," not in ln or float(ln.split(",")[0]) >= ttff]
        log = tmp_path / f"late{ttff:g}.log"
        log.write_text("\n".join(keep) + "\n")
        s = run(tmp_path, "--input", str(log))
        assert s["errors"]["position_rmse_m"] < RAW_GPS_RMS / 2, ttff
        assert s["sensors"]["gps"]["rejected"] <= 2, ttff
        assert "static fixes before the first moving one" in s["info"]["gps"]["decoder"]["origin_source"]


def test_without_magnetometer_samples_in_the_alignment_the_heading_is_left_to_the_gps(tmp_path):
    """No magnetometer line reaches the alignment: starting from the config's yaw guess (here 90 deg off
    the truth) held at its sd 0.02 rad, every GPS fix would be gated out. The heading is unknown (sd ~104 deg)
    and a sigma-point filter takes it from the GPS
    velocity. (The EKF's linearisation cannot bridge a 90 deg heading error.)"""
    lines = (ROOT / "recordings" / "car_gps_mag.log").read_text().splitlines()
    log = tmp_path / "nomag.log"
    log.write_text("\n".join(ln for ln in lines if ",mag," not in ln) + "\n")
    text = CONFIG.read_text().replace("q: [1, 0, 0, 0]", "q: [0.7071068, 0, 0, 0.7071068]")
    assert "0.7071068" in text
    cfg = tmp_path / "yaw90.yaml"
    cfg.write_text(text.replace("recording: ../recordings/car_gps_mag.log", f"recording: {log}"))
    out = tmp_path / "s.json"
    assert main(["run", str(cfg), "-q", "--filter", "ukf", "--summary-json", str(out)]) == 0
    s = json.loads(out.read_text())
    assert s["errors"]["position_rmse_m"] < RAW_GPS_RMS / 2
    assert s["sensors"]["gps"]["rejected"] <= 2


def test_the_decoder_and_the_aligning_model_say_so_in_the_run():
    """The nmea decoder's moving start and the magnetometer's alignment without samples queue a warning
    (take_events); the run now reports what a decoder or a model queues, as it does a solver's."""
    from fusion import pipeline
    from fusion.config import load_system

    lines = (ROOT / "recordings" / "car_gps_mag.log").read_text().splitlines()
    cases = {"heading unknown": [ln for ln in lines if ",mag," not in ln],
             "no static GPS fix": [ln for ln in lines if ",gps," not in ln or ln.startswith("#")
                                   or float(ln.split(",")[0]) >= 45.0]}
    for needle, log in cases.items():
        events = []
        pipeline.run(load_system(CONFIG), log, on_event=events.append)
        assert [e for e in events if e.kind == "warning" and needle in e.detail], needle


@pytest.mark.parametrize("filter_name", ["ekf", "ukf"])
def test_a_pause_of_every_stream_in_a_corner_is_bridged(tmp_path, filter_name):
    """All streams silent for 10 s from 80 s, in the first corner (~90 deg at 0.33 rad/s). Integrating the
    held sample (the corner's rate) over the 10 s would put the attitude 100+ deg off and gate out every
    later fix; the state coasts past hold_after with a bounded hold noise,
    and the gps recovery re-sets a filter that is locked out all the same (the UKF, once)."""
    lines = (ROOT / "recordings" / "car_gps_mag.log").read_text().splitlines()
    log = tmp_path / "pause.log"
    log.write_text("\n".join(ln for ln in lines if ln.startswith("#") or not 80.0 <= float(ln.split(",")[0]) < 90.0)
                   + "\n")
    s = run(tmp_path, "--input", str(log), "--filter", filter_name)
    assert s["errors"]["position_rmse_m"] < 10.0
    assert s["sensors"]["gps"]["rejected"] < 10 and s["health"]["resets"] <= 1


@pytest.mark.parametrize("start,filter_name", [(80.0, "ekf"), (160.0, "ekf"), (160.0, "ukf")])
def test_an_imu_dropout_while_gps_and_magnetometer_go_on(tmp_path, start, filter_name):
    """The IMU alone silent for 10 s (in the first corner at 80 s; at 160 s), GPS and magnetometer going on:
    the magnetometer's 6 Hz cuts the gap into ~60 predictions; a hold noise restarted at each (~1/30 of
    its sd after 5 s) would leave the filter sure of an attitude it had lost (from 160 s, 12.9 m RMSE, max
    122 m, GPS refused for 13 s, a reset, for a 5 s gap). Each prediction knows how
    long the sample has been held (fusion.api.HoldsInput) and adds what accrued over its stretch."""
    from fusion.testing.faults import cut_recording

    log = tmp_path / "imu_dropout.log"
    log.write_text("\n".join(cut_recording(ROOT / "recordings" / "car_gps_mag.log",
                                           lambda t, ln: start <= t < start + 10.0 and ",imu," in ln)) + "\n")
    s = run(tmp_path, "--input", str(log), "--filter", filter_name)
    assert s["errors"]["position_rmse_m"] < 1.8                # 1.35 m without the dropout
    assert s["errors"]["position_max_m"] < 8.0
    assert s["health"]["resets"] == 0 and s["sensors"]["gps"]["rejected"] <= 3
