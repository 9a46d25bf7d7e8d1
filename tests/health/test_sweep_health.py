"""``fusion sweep`` records the health rule's judgement per trial and counts degraded trials (issue 28
item 2), on both the pipeline engines and the batch engine."""
from __future__ import annotations

import csv
from pathlib import Path

import pytest

from fusion.cli import main
from fusion.sweep.report import degraded_counts

ROOT = Path(__file__).resolve().parents[2]
UWB = str(ROOT / "configs" / "uwb_pv_ukf.yaml")


@pytest.mark.parametrize("engine", ["serial", "batch"])
def test_sweep_rows_say_which_trials_are_degraded(engine, tmp_path, capsys):
    """A start 25 m off with a 0.3 m sd is locked out (most ranges rejected) on every seed; the config's own
    start is not. Both variants in one sweep: the rows and the report tell them apart."""
    out = tmp_path / "r.csv"
    code = main(["sweep", UWB, "--seeds", "2", "--engine", engine, "--no-progress", "-o", str(out),
                 "--param", "initial.mean.p=[3.0, 3.0],[25.0, 15.0]", "--param", "initial.sd.p=0.3"])
    assert code == 0
    rows = list(csv.DictReader(out.open(encoding="utf-8")))
    assert len(rows) == 4 and {r["status"] for r in rows} == {"ok"}
    by = {(r["param.initial.mean.p"], r["seed"]): r for r in rows}
    for seed in ("0", "1"):
        assert by[("[3.0, 3.0]", seed)]["degraded"] == "0" and by[("[3.0, 3.0]", seed)]["health"] == ""
        bad = by[("[25.0, 15.0]", seed)]
        assert bad["degraded"] == "1" and bad["health"].startswith("uwb: ") and "updates rejected" in bad["health"]
    report = capsys.readouterr().out
    assert "| variant | n | failed | degraded |" in report
    assert "2 of 4 trial(s) degraded" in report


def test_degraded_counts_per_variant():
    rows = [{"status": "ok", "degraded": 1, "filter": "ukf"}, {"status": "ok", "degraded": 0, "filter": "ukf"},
            {"status": "ok", "degraded": "1", "filter": "ekf"}, {"status": "error", "degraded": 1, "filter": "ekf"}]
    assert degraded_counts(rows, ["filter"]) == {"ukf": 1, "ekf": 1}
