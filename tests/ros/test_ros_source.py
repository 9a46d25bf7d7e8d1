"""``fusion run --input BAG``: a bag replayed directly gives the run of its imported recording; an MCAP that is
no ROS 2 bag is one error line."""
from __future__ import annotations

import json

import pytest

from bagmaker import storage_file, write_bag
from ros_helpers import ROOT, fusion

EKF = ROOT / "docs" / "examples" / "ros" / "ekf.yaml"


@pytest.mark.slow
def test_bag_input_is_the_imported_recording(tmp_path):
    write_bag(tmp_path / "r", "mcap", duration=10.0)
    bag = storage_file(tmp_path / "r", "mcap")
    (tmp_path / "map.yaml").write_text("reference: {topic: /odometry/filtered}\n")
    assert fusion("import", bag, "--map", tmp_path / "map.yaml", "-o", tmp_path / "r.log") == 0
    assert fusion("import-config", EKF, "--recording", tmp_path / "r.log", "-o", tmp_path / "r.yaml") == 0
    out = {}
    for name, source in (("log", tmp_path / "r.log"), ("bag", f"rosbag://{bag}?map={tmp_path / 'map.yaml'}")):
        js = tmp_path / f"{name}.json"
        assert fusion("run", tmp_path / "r.yaml", "--input", source, "--summary-json", js, "--quiet",
                      "--no-progress") == 0
        out[name] = json.loads(js.read_text())
    assert out["bag"]["agreement"] == out["log"]["agreement"]
    assert out["bag"]["sensors"] == out["log"]["sensors"]


def test_an_mcap_that_is_no_bag_is_one_error_line(tmp_path, capsys):
    junk = tmp_path / "x.mcap"
    junk.write_bytes(b"\x89MCAP0\r\n" + b"\0" * 64)
    cfg = tmp_path / "c.yaml"
    assert fusion("import-config", EKF, "-o", cfg) == 0
    capsys.readouterr()
    assert fusion("run", cfg, "--input", junk, "--quiet", "--no-progress") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a readable ROS bag" in err[0], err
