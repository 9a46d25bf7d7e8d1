"""A flight log without GPS runs through the shipped PX4 config unchanged: the filter does not wait for a
fix that never comes (initial.from_sensor: gps), starts from the reference attitude and says so once; the
attitude is then the estimate to read (here within the tilt a gyro-only prediction with magnetometer
heading keeps over the 40 s flight: 10 deg, against a filter that never started)."""
from __future__ import annotations

import json
import sys

from import_helpers import ROOT, fusion_import
from fusion.cli import main

sys.path.insert(0, str(ROOT / "experiments"))


def test_px4_config_on_a_log_without_gps(tmp_path, capsys):
    import flight_layouts as fl

    fl.write("ulog_new", fl.flight(), tmp_path / "f.ulg")
    assert fusion_import(tmp_path / "f.ulg", "-o", tmp_path / "f.log", "--sensors", "imu", "mag", "reference") == 0
    capsys.readouterr()
    out = tmp_path / "s.json"
    assert main(["run", str(ROOT / "configs" / "px4_ins_gps_mag.yaml"), "--input", str(tmp_path / "f.log"),
                 "--summary-json", str(out)]) == 0
    err = capsys.readouterr().err
    assert err.count("the recording has no 'gps' stream") == 1 and "initial_attitude" in err
    s = json.loads(out.read_text())
    assert s["sensors"]["imu"]["used"] == s["sensors"]["imu"]["received"]
    assert s["sensors"]["initial_attitude"]["used"] == 1 and s["sensors"]["mag"]["used"] > 300
    assert s["agreement"]["attitude_max_deg"] < 10.0


def test_px4_config_on_an_imu_only_log_gives_attitude_estimates(tmp_path, capsys):
    """No GPS and no magnetometer: no update to emit an estimate at, so the run emits them at 10 Hz by
    prediction (said in the warning); the attitude is the reference's start integrated by the gyros."""
    import flight_layouts as fl

    fl.write("ulog_new", fl.flight(), tmp_path / "f.ulg")
    assert fusion_import(tmp_path / "f.ulg", "-o", tmp_path / "f.log", "--sensors", "imu", "reference") == 0
    capsys.readouterr()
    out, est = tmp_path / "s.json", tmp_path / "e.csv"
    assert main(["run", str(ROOT / "configs" / "px4_ins_gps_mag.yaml"), "--input", str(tmp_path / "f.log"),
                 "-o", str(est), "--summary-json", str(out)]) == 0
    assert "estimates also at 10 Hz" in capsys.readouterr().err
    rows = est.read_text().splitlines()[1:]
    assert 390 <= len(rows) <= 401                                   # 40 s at 10 Hz
    assert json.loads(out.read_text())["agreement"]["attitude_max_deg"] < 10.0
