"""Ctrl-C after the input was read, while smoothing (issue 28 item 4): the smoothed output is incomplete,
so nothing appears under its final name (no cut CSV), the summary is written and says so, exit 130."""
import json
from pathlib import Path

import pytest

import fusion.smoothing.run as smoothing_run
from fusion.cli import main

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"


def interrupt(*args, **kwargs):
    raise KeyboardInterrupt


def interrupt_after(n: int):
    """``smoothed_estimates`` that yields ``n`` smoothed estimates, then Ctrl-C."""
    real = smoothing_run.smoothed_estimates

    def cut(*args, **kwargs):
        for k, est in enumerate(real(*args, **kwargs)):
            if k == n:
                raise KeyboardInterrupt
            yield est
    return cut


@pytest.mark.parametrize("where, written", [("smooth", 0), ("smoothed_estimates", 25)])
@pytest.mark.parametrize("option", [["--smooth"], ["--smooth-lag", "1.0"]])
def test_interrupt_while_smoothing_leaves_no_cut_output_and_a_summary(tmp_path, capsys, monkeypatch, where,
                                                                       written, option):
    if option[0] == "--smooth-lag" and where == "smooth":
        monkeypatch.setattr(smoothing_run.FixedLag, "finish", interrupt)   # the fixed lag's last window
    else:
        monkeypatch.setattr(smoothing_run, where, interrupt if where == "smooth" else interrupt_after(written))
    out, summary = tmp_path / "smoothed.csv", tmp_path / "summary.json"
    code = main(["run", str(CONFIG), *option, "-o", str(out), "--summary-json", str(summary), "-q"])
    assert code == 130
    assert not out.exists()                                  # no cut CSV under the final name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]   # no temporary file left either
    data = json.loads(summary.read_text())                  # the summary is written
    assert data["interrupted"] is True and "smoothed output is incomplete" in data["smoothed"]["interrupted"]
    assert data["sensors"]["uwb"]["used"] > 0               # the forward run's figures are there
    err = capsys.readouterr().err
    assert "while smoothing: the smoothed output is incomplete and was not written" in err
    assert "interrupted" in err.splitlines()[-1]


def test_an_uninterrupted_smoothed_run_writes_its_output(tmp_path, capsys):
    out, summary = tmp_path / "smoothed.csv", tmp_path / "summary.json"
    assert main(["run", str(CONFIG), "--smooth", "-o", str(out), "--summary-json", str(summary), "-q"]) == 0
    data = json.loads(summary.read_text())
    assert "interrupted" not in data and data["smoothed"]["estimates"] == len(out.read_text().splitlines()) - 1
