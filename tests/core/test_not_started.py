"""A run whose filter never starts says so: the summary's ``not_started`` names what it waited for, and
the printed summary leads with it instead of "no truth in the input"."""
from __future__ import annotations

import json
from pathlib import Path

from fusion.cli import main

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "abps_ins.yaml"           # initial.from_sensor: abps
RECORDING = ROOT / "recordings" / "abps_mine.log"


def test_a_run_without_the_initialising_sensor_reports_it(tmp_path, capsys):
    lines = [ln for ln in RECORDING.read_text().splitlines()[:4000] if ",abps," not in ln]
    log, out = tmp_path / "no_abps.log", tmp_path / "s.json"
    log.write_text("\n".join(lines) + "\n")
    assert main(["run", str(CONFIG), "--input", str(log), "--summary-json", str(out)]) == 0
    summary = json.loads(out.read_text())
    assert "never initialised" in summary["not_started"] and "'abps'" in summary["not_started"]
    printed = capsys.readouterr().out
    assert "never initialised" in printed and "no truth in the input" not in printed


def test_a_started_run_has_no_such_note(tmp_path):
    lines = RECORDING.read_text().splitlines()[:4000]
    log, out = tmp_path / "part.log", tmp_path / "s.json"
    log.write_text("\n".join(lines) + "\n")
    assert main(["run", str(CONFIG), "--input", str(log), "-q", "--summary-json", str(out)]) == 0
    assert "not_started" not in json.loads(out.read_text())
