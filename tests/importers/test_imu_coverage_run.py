"""``fusion run`` reads the IMU coverage an importer wrote in the header (fusion.imu_coverage): below the
input sensor's ``min_coverage`` or above its ``max_rotation_deg`` one warning, and the figures in the
summary's ``health``; within them, no warning. The shipped synthetic flight with its header edited (the
figures of a PX4 log written at 8.6 Hz: 4 ms of each 116 ms, 143 deg/s)."""
from __future__ import annotations

import json

import yaml

from import_helpers import ROOT
from fusion.cli import main
from fusion.imu_coverage import assess

LOW = 4e-3 / 0.116
TURN = 143.0 * 0.116


def test_assess_limits():
    meta = {"imu_coverage_fraction": f"{LOW:.4g}", "imu_rotation_per_sample_deg": f"{TURN:.3g}"}
    facts, warning = assess("imu", meta)
    assert facts["insufficient"] and "0.0345 of the time" in warning and "16.6 deg" in warning
    facts, warning = assess("imu", meta, min_coverage=0.01, max_rotation_deg=20.0)
    assert warning is None and not facts["insufficient"]
    assert assess("imu", {}) == (None, None)                       # the header says nothing: nothing said
    facts, warning = assess("imu", {"imu_coverage_fraction": "0.98"})
    assert warning is None and facts["rotation_per_sample_deg"] is None


def _low(tmp_path):
    text = (ROOT / "recordings" / "flight_synthetic.log").read_text()
    assert "# imu_rotation_per_sample_deg: " in text
    lines = [ln for ln in text.splitlines() if not ln.startswith("# imu_rotation_per_sample_deg")]
    lines.insert(1, f"# imu_rotation_per_sample_deg: {TURN:.3g}\n# imu_coverage_fraction: {LOW:.4g}")
    path = tmp_path / "low.log"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_run_warns_once_and_ends_degraded(tmp_path, capsys):
    """A log that cannot be dead-reckoned: one warning, the figures in the summary's health, and exit 4 (the
    health rule's imu_coverage finding) rather than 0."""
    out = tmp_path / "s.json"
    cfg = ROOT / "configs" / "ardupilot_ins_gps_mag.yaml"
    assert main(["run", str(cfg), "--input", str(_low(tmp_path)), "--summary-json", str(out)]) == 4
    err = capsys.readouterr().err
    assert err.count("IMU coverage:") == 1, err
    assert "degraded" in err.strip().splitlines()[-1] and "imu" in err.strip().splitlines()[-1]
    health = json.loads(out.read_text())["health"]
    cov = health["imu_coverage"]["imu"]
    assert cov["insufficient"] and cov["fraction"] == float(f"{LOW:.4g}")
    assert health["degraded"] and health["findings"][0]["kind"] == "imu_coverage"


def test_limits_from_the_config(tmp_path, capsys):
    cfg = yaml.safe_load((ROOT / "configs" / "ardupilot_ins_gps_mag.yaml").read_text())
    cfg["recording"] = str(ROOT / "recordings" / "flight_synthetic.log")
    cfg["sensors"]["imu"].update(min_coverage=0.01, max_rotation_deg=20.0)
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    out = tmp_path / "s.json"
    assert main(["run", str(tmp_path / "c.yaml"), "--input", str(_low(tmp_path)), "--summary-json", str(out)]) == 0
    assert "IMU coverage:" not in capsys.readouterr().err
    assert json.loads(out.read_text())["health"]["imu_coverage"]["imu"]["insufficient"] is False
