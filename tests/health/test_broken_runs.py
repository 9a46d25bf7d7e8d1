"""Runs whose estimate disagrees with their data end with exit 4 and one last line naming the sensor, the
figures and the likely causes (issue 28 items 2 and 5); --allow-degraded and health.allow_degraded give 0."""
from __future__ import annotations

import json

import pytest
import yaml

from fusion.cli import main
from fusion.health import DEGRADED_EXIT

from cases import gps_latency, renumbered_receivers, wide_start, wrong_field

# (case, sensor named on the last line, what the line must say, the first likely cause)
CASES = [
    (wrong_field, "mag", "updates rejected", "the config's constants against the recording's header"),
    (gps_latency, "gps", "dropped as late", "a latency (sensors.gps.time_offset 0 s"),
    (wide_start, "uwb", "updates rejected", "the config's constants"),
    (renumbered_receivers, "us", "errors against truth", "a receiver array of 32 in the header"),
]


@pytest.mark.parametrize("make, sensor, figures, cause", CASES, ids=[c[0].__name__ for c in CASES])
def test_broken_run_is_degraded_with_one_line_naming_the_cause(make, sensor, figures, cause, tmp_path, capsys):
    cfg = make(tmp_path)
    out = tmp_path / "s.json"
    code = main(["run", str(cfg), "-q", "--summary-json", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == DEGRADED_EXIT == 4
    last = err[-1]
    assert last.startswith("fusion run: degraded: the estimate cannot be trusted (exit 4;")
    assert f": {sensor}: " in last and figures in last
    causes = last.split("likely causes, in order: ", 1)[1]
    assert causes.startswith("(1) ") and cause in causes.split("; (2)")[0]
    health = json.loads(out.read_text())["health"]
    assert health["degraded"] is True and health["findings"][0]["sensor"] == sensor


def test_allow_degraded_option_and_config_key_give_exit_0(tmp_path, capsys):
    cfg = wide_start(tmp_path)
    assert main(["run", str(cfg), "-q", "--allow-degraded"]) == 0
    assert "degraded, exit 0 as allowed" in capsys.readouterr().err.strip().splitlines()[-1]
    data = yaml.safe_load(cfg.read_text())
    data["health"] = {"allow_degraded": True}
    cfg.write_text(yaml.safe_dump(data))
    assert main(["run", str(cfg), "-q"]) == 0


def test_a_limit_the_config_sets_is_used(tmp_path, capsys):
    """health.max_unused_share 0.9 lets the wide start's 73 % rejected pass the share test; its NEES against
    truth is still far over the limit, so the run is degraded by that finding instead."""
    cfg = wide_start(tmp_path)
    data = yaml.safe_load(cfg.read_text())
    data["health"] = {"max_unused_share": 0.9}
    cfg.write_text(yaml.safe_dump(data))
    assert main(["run", str(cfg), "-q"]) == 4
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert "uwb: errors against truth: NEES" in last and "updates rejected" not in last
    data["health"] = {"max_unused_share": 0.9, "truth": {"nees_per_dof": None}, "lockout_s": 1000.0}
    cfg.write_text(yaml.safe_dump(data))
    assert main(["run", str(cfg), "-q"]) == 0


def test_an_unknown_health_key_is_one_exit_2_line(tmp_path, capsys):
    cfg = wide_start(tmp_path)
    data = yaml.safe_load(cfg.read_text())
    data["health"] = {"max_unused_shares": 0.4}
    cfg.write_text(yaml.safe_dump(data))
    assert main(["run", str(cfg), "-q"]) == 2
    err = capsys.readouterr().err
    assert "health.max_unused_shares" in err or "max_unused_shares" in err
