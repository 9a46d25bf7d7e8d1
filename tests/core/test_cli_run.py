"""End to end: `fusion run`, `fusion validate`, `fusion plugins` through the CLI entry point."""
import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from fusion.cli import main
from fusion.logformat import checksum

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"
RECORDING = ROOT / "recordings" / "example_2d.log"


def test_run_example_reports_rmse_against_truth(tmp_path, capsys):
    out_csv, summ, png = tmp_path / "est.csv", tmp_path / "s.json", tmp_path / "p.png"
    assert main(["run", str(CONFIG), "--output", str(out_csv), "--summary-json", str(summ), "--plot", str(png)]) == 0
    s = json.loads(summ.read_text())
    for key in ("config", "filter", "input", "duration_s", "wall_s", "steps", "us_per_predict", "us_per_update",
                "sensors", "errors", "consistency"):
        assert key in s
    assert s["sensors"]["uwb"]["received"] == s["sensors"]["uwb"]["used"] + s["sensors"]["uwb"]["rejected"]
    # Ranges of 0.1 m noise to four well-placed beacons: the fix is far better than the noise.
    assert 0.0 < s["errors"]["position_rmse_m"] < 0.15
    rows = list(csv.DictReader(out_csv.open()))
    assert len(rows) == s["steps"]["update"]
    assert {"t", "px", "py", "vx", "vy", "sd_px", "sd_vy"} <= set(rows[0])
    # The CSV's errors recomputed independently from the truth lines of the recording agree with the summary.
    truth = np.array([[float(v) for v in line.split(",")[2:]] for line in RECORDING.read_text().splitlines()
                      if ",truth," in line])
    tt = np.array([float(line.split(",")[0]) for line in RECORDING.read_text().splitlines() if ",truth," in line])
    t = np.array([float(r["t"]) for r in rows])
    est = np.array([[float(r["px"]), float(r["py"])] for r in rows])
    ref = np.column_stack([np.interp(t, tt, truth[:, 0]), np.interp(t, tt, truth[:, 1])])
    rmse = np.sqrt(np.mean(np.sum((est - ref) ** 2, axis=1)))
    assert rmse == pytest.approx(s["errors"]["position_rmse_m"], rel=1e-3)
    assert png.stat().st_size > 10_000
    assert "position RMSE" in capsys.readouterr().out


def test_filter_override_switches_filter(tmp_path):
    summ = tmp_path / "s.json"
    assert main(["run", str(CONFIG), "--filter", "ekf", "-q", "--summary-json", str(summ)]) == 0
    assert json.loads(summ.read_text())["filter"] == "ekf"
    assert main(["run", str(CONFIG), "--filter-param", "alpha=0.3", "-q", "--summary-json", str(summ), "--force"]) == 0
    assert json.loads(summ.read_text())["filter"] == "ukf"


def test_unknown_filter_is_a_user_error(capsys):
    assert main(["run", str(CONFIG), "--filter", "ufk", "-q"]) == 2
    err = capsys.readouterr().err
    assert "did you mean 'ukf'" in err and "Traceback" not in err


def test_malformed_lines_counted_and_skipped(tmp_path):
    lines = RECORDING.read_text().splitlines()
    idx = [i for i, line in enumerate(lines) if line.startswith(("1", "2")) and ",uwb," in line][:3]
    lines[idx[0]] = lines[idx[0]].replace(",uwb,", ",uwb,xx,")          # wrong field count
    lines[idx[1]] = lines[idx[1]].rsplit(",", 1)[0] + ",1.2.3"           # bad number
    wrong = "%02X" % (int(checksum(lines[idx[2]]), 16) ^ 0xFF)
    lines[idx[2]] = lines[idx[2]] + "*" + wrong                           # bad checksum
    bad = tmp_path / "bad.log"
    bad.write_text("\n".join(lines) + "\n")
    summ = tmp_path / "s.json"
    assert main(["run", str(CONFIG), "--input", str(bad), "-q", "--summary-json", str(summ)]) == 0
    s = json.loads(summ.read_text())
    assert s["sensors"]["uwb"]["malformed"] == 3
    assert s["errors"]["position_rmse_m"] < 0.15


@pytest.mark.parametrize("content,expect", [
    (None, "no such recording"),
    (b"", "empty"),
    (b"\x00\x01\x02binary\xff" * 10, "binary"),
    ("0.0,uwb,B1,1.0\n".encode("utf-16"), "binary"),
    (b"\xe9t\xe9,uwb,B1,1.0\n" * 5, "not UTF-8"),
])
def test_unusable_recording_is_one_clear_line(tmp_path, capsys, content, expect):
    path = tmp_path / "rec.log"
    if content is not None:
        path.write_bytes(content)
    assert main(["run", str(CONFIG), "--input", str(path), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert expect in err and str(path) in err and len(err.splitlines()) == 1


def test_validate_catches_dimension_and_unknown_plugin(tmp_path, capsys):
    cfg = tmp_path / "c.yaml"
    text = CONFIG.read_text().replace("../recordings/example_2d.log", str(RECORDING))
    cfg.write_text(text.replace("noise: {sd: 0.1}", "noise: {R: [[0.01, 0], [0, 0.01]]}"))
    cfg2 = tmp_path / "d.yaml"
    cfg2.write_text(text.replace("model: range", "model: rnage"))
    assert main(["validate", str(CONFIG), str(cfg), str(cfg2)]) == 2
    out, err = capsys.readouterr()
    assert "example_2d.yaml: ok" in out
    assert "must be 1 x 1" in err and "did you mean 'range'" in err


def test_plugins_lists_builtins(capsys):
    assert main(["plugins"]) == 0
    out = capsys.readouterr().out
    for name in ("pv", "range", "kf", "ekf", "ukf", "chi2", "line"):
        assert name in out


def test_config_without_recording_needs_input(tmp_path, capsys):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("\n".join(l for l in CONFIG.read_text().splitlines() if not l.startswith("recording:")))
    assert main(["run", str(cfg), "-q"]) == 2
    assert "--input" in capsys.readouterr().err


def test_internal_error_mid_run_says_how_far_it_got(tmp_path, monkeypatch, capsys):
    """A bug in the filter itself ends the run (exit 1) saying how far it got; what was computed is kept.
    (A plugin failing on one message is that message's problem: tests/core/test_clock.py.)"""
    from fusion_plugins.filters.ukf import UnscentedKalmanFilter

    original = UnscentedKalmanFilter.update

    def broken(self, belief, *args, **kwargs):
        if belief.t > 30.0:
            raise RuntimeError("plugin bug")
        return original(self, belief, *args, **kwargs)

    monkeypatch.setattr(UnscentedKalmanFilter, "update", broken)
    out_csv = tmp_path / "est.csv"
    assert main(["run", str(CONFIG), "-q", "--output", str(out_csv)]) == 1
    err = capsys.readouterr().err
    assert "internal error" in err and "plugin bug" in err and "got as far as t = 30.0" in err
    # What was computed before the failure is on disk (flushed as it went).
    rows = list(csv.DictReader(out_csv.open()))
    assert rows and 29.5 < float(rows[-1]["t"]) <= 30.0
