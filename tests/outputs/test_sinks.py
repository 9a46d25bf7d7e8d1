"""fusion.sinks.estimates and fusion.sinks.summary: files readable while the run goes on, right columns."""
import csv
import json
import math

from pathlib import Path

import numpy as np
import pytest

from fusion.api import Belief, BuildContext, Estimate, FusionError, StateLayout
from fusion.sinks.estimates import EstimateWriter, format_for
from fusion.sinks.summary import write_summary_json

LAY = StateLayout.parse("p:2 v:2")


def estimate(t, reason="update", sensor="uwb"):
    x = np.array([1.0, 2.0, 3.0, 4.0]) * t
    P = np.diag([0.25, 1.0, 4.0, 9.0])
    return Estimate(t, Belief(t, x, P=P), reason, sensor)


def test_csv_columns_and_rows_readable_before_close(tmp_path):
    path = tmp_path / "out.csv"
    w = EstimateWriter(path, LAY)
    assert w.format == "csv"
    live = Path(w.writing)                                     # the temporary name beside the target
    assert live.parent == path.parent and not path.exists()
    # header on disk before any estimate
    assert live.read_text().splitlines() == ["t,px,py,vx,vy,sd_px,sd_py,sd_vx,sd_vy,reason,sensor"]
    w.on_estimate(estimate(0.5))
    w.on_estimate(estimate(1.0, reason="output", sensor=None))
    rows = list(csv.DictReader(live.open()))                 # read back before close: flushed
    assert len(rows) == 2
    assert float(rows[0]["t"]) == 0.5 and float(rows[0]["vy"]) == 2.0
    assert [float(rows[1][f"sd_{n}"]) for n in LAY.names] == [0.5, 1.0, 2.0, 3.0]
    assert rows[0]["reason"] == "update" and rows[0]["sensor"] == "uwb"
    assert rows[1]["reason"] == "output" and rows[1]["sensor"] == ""
    w.close()
    assert list(csv.DictReader(path.open())) == rows and not live.exists()  # renamed into place whole
    w.close()                                                  # idempotent
    with pytest.raises(ValueError, match="closed"):
        w.on_estimate(estimate(2.0))


def test_jsonl_rows_readable_before_close(tmp_path):
    path = tmp_path / "out.jsonl"
    with EstimateWriter(path, LAY) as w:
        assert w.format == "jsonl"
        w.on_estimate(estimate(2.0))
        bad = Estimate(3.0, Belief(3.0, np.array([np.nan, 0, 0, 0]), P=np.eye(4)), "output")
        w.on_estimate(bad)
        lines = Path(w.writing).read_text().splitlines()
        objs = [json.loads(line) for line in lines]            # strict JSON (no NaN token)
    assert list(objs[0]) == ["t", *LAY.names, *(f"sd_{n}" for n in LAY.names), "reason", "sensor"]
    assert objs[0]["px"] == 2.0 and objs[0]["sd_vy"] == 3.0 and objs[0]["sensor"] == "uwb"
    assert objs[1]["px"] is None and objs[1]["sensor"] is None


def test_format_by_suffix_and_errors(tmp_path):
    assert format_for("a.CSV") == "csv" and format_for("a.ndjson") == "jsonl" and format_for("-") == "csv"
    with pytest.raises(FusionError, match="jsonl"):
        format_for("a.json")
    with pytest.raises(FusionError, match="cannot write"):
        EstimateWriter(tmp_path / "missing" / "out.csv", LAY)
    w = EstimateWriter(tmp_path / "x.csv", LAY)
    with pytest.raises(ValueError, match="elements"):
        w.on_estimate(Estimate(0.0, Belief(0.0, np.zeros(3), P=np.eye(3)), "output"))
    w.close()


def test_registered_sink_builds_from_params_and_context(tmp_path):
    from fusion.registry import make_plugin_manager

    _, reg = make_plugin_manager()
    cls = reg.get("sink", "estimates")
    assert cls is EstimateWriter
    path = tmp_path / "reg.csv"
    sink = cls(cls.Params(path=str(path)), BuildContext(layout=LAY))
    sink.on_estimate(estimate(1.0))
    sink.close()
    assert path.read_text().splitlines()[0].startswith("t,px,py,vx,vy,sd_px")
    with pytest.raises(Exception):
        cls.Params(path="x.csv", colour="red")                 # extra="forbid"


def test_summary_json_numpy_and_nonfinite(tmp_path):
    path = tmp_path / "summary.json"
    s = {"config": "c.yaml", "duration_s": np.float64(12.5), "steps": {"predict": np.int64(10), "update": 3},
         "us_per_update": None, "errors": {"position_rmse_m": float("nan")}, "arr": np.arange(3)}
    write_summary_json(path, s)
    back = json.loads(path.read_text())
    expected = {"config": "c.yaml", "duration_s": 12.5, "steps": {"predict": 10, "update": 3},
                "us_per_update": None, "errors": {"position_rmse_m": None}, "arr": [0, 1, 2]}
    assert back == expected  # numpy scalars and arrays as JSON numbers and lists, NaN as null
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
    with pytest.raises(FusionError, match="cannot write summary"):
        write_summary_json(tmp_path / "nope" / "s.json", s)
