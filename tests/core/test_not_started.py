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
    """Exit 2 (a log this config cannot use is a user error, and a script must see it), the summary
    written and printed all the same."""
    lines = [ln for ln in RECORDING.read_text().splitlines()[:4000] if ",abps," not in ln]
    log, out = tmp_path / "no_abps.log", tmp_path / "s.json"
    log.write_text("\n".join(lines) + "\n")
    assert main(["run", str(CONFIG), "--input", str(log), "--summary-json", str(out)]) == 2
    summary = json.loads(out.read_text())
    assert "never initialised" in summary["not_started"] and "'abps'" in summary["not_started"]
    assert "no message of the config's sensors" not in summary["not_started"]    # imu samples were there
    captured = capsys.readouterr()
    assert "never initialised" in captured.out and "no truth in the input" not in captured.out
    assert captured.err.strip().splitlines()[-1].startswith("fusion run: error: no estimate was made")


def test_a_log_of_other_sensors_says_which_it_had(tmp_path, capsys):
    log, out, csv = tmp_path / "other.log", tmp_path / "s.json", tmp_path / "e.csv"
    log.write_text("# fusion-log 1\n1.0,gps,1,2\nnot a line\n2.0,baro,3\n2.5,gps,4,5\n")
    assert main(["run", str(CONFIG), "--input", str(log), "-q", "--summary-json", str(out), "-o", str(csv)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    # -q hides the table only: the warnings (unknown sensors, the malformed line) come first, then one error line
    assert "no message of the config's sensors (imu, abps) was in the input, which had baro, gps" in err[-1]
    assert [line.split(":")[0] for line in err[:-1]] == ["warning", "malformed", "warning"]
    summary = json.loads(out.read_text())
    assert summary["ignored_sensors"] == {"gps": 2, "baro": 1} and summary["sensors"]["?"]["malformed"] == 1
    assert csv.read_text().startswith("t,px,")      # the output exists (a header: nothing to write)


def test_a_started_run_has_no_such_note(tmp_path):
    lines = RECORDING.read_text().splitlines()[:4000]
    log, out = tmp_path / "part.log", tmp_path / "s.json"
    log.write_text("\n".join(lines) + "\n")
    assert main(["run", str(CONFIG), "--input", str(log), "-q", "--summary-json", str(out)]) == 0
    assert "not_started" not in json.loads(out.read_text())
