"""A reorder buffer (scheduler.max_latency > 0) releases several messages in one go: input samples released
after a measurement (which integrates the pending samples up to its own time) are integrated too, none
lost: every IMU sample received is used, and the estimate equals the one without a buffer (an imported log
is in time order, so the buffer changes nothing but when messages are released)."""
from __future__ import annotations

import json
from pathlib import Path

import yaml

from fusion.cli import main

ROOT = Path(__file__).resolve().parents[2]


def _run(tmp_path, latency: float, name: str) -> dict:
    cfg = yaml.safe_load((ROOT / "configs" / "ardupilot_ins_gps_mag.yaml").read_text())
    cfg["recording"] = str(ROOT / "recordings" / "flight_synthetic.log")
    cfg["scheduler"]["max_latency"] = latency
    cfg["sensors"]["gps"].pop("time_offset", None)
    (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(cfg))
    lines = [ln for ln in (ROOT / "recordings" / "flight_synthetic.log").read_text().splitlines()
             if ln.startswith("#") or float(ln.split(",")[0]) < 10.0]
    (tmp_path / "cut.log").write_text("\n".join(lines) + "\n")
    out = tmp_path / f"{name}.json"
    assert main(["run", str(tmp_path / f"{name}.yaml"), "--input", str(tmp_path / "cut.log"), "-q",
                 "--summary-json", str(out), "--force"]) == 0
    return json.loads(out.read_text())


def test_max_latency_loses_no_input_sample(tmp_path):
    base, buffered = _run(tmp_path, 0.0, "none"), _run(tmp_path, 0.25, "buffered")
    imu = buffered["sensors"]["imu"]
    assert imu["used"] == imu["received"] == base["sensors"]["imu"]["received"]
    for key in ("position_rmse_m", "attitude_rmse_deg"):
        assert abs(buffered["agreement"][key] - base["agreement"][key]) < 1e-6 * max(1.0, base["agreement"][key])
