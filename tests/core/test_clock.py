"""Time sanity (issue 10 item 2, fusion/clock.py): wild stamps never move the horizon, clock jumps and
restarts are detected and re-synchronised, gaps are bounded.

Every time asserted here is a sensor stamp of the recording (or the span they cover, ``duration_s``),
set by the test's own re-timing of the lines; nothing measures how long the code takes (speed is in
benchmarks/)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from fusion import pipeline
from fusion.api import Message
from fusion.cli import main
from fusion.clock import ClockGuard
from fusion.config import load_system

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "configs" / "example_2d.yaml"
ABPS = ROOT / "configs" / "abps_ins.yaml"
LINES = (ROOT / "recordings" / "example_2d.log").read_text().splitlines()


def _run(lines, config=EXAMPLE):
    system = load_system(config)
    return pipeline.run(system, [ln + "\n" for ln in lines]).summary


@pytest.fixture(scope="module")
def reference():
    return _run(LINES)


def _retime(lines, fn, sensors=None):
    out = []
    for ln in lines:
        if ln.startswith("#"):
            out.append(ln)
            continue
        t, rest = ln.split(",", 1)
        if sensors is None or rest.split(",", 1)[0] in sensors:
            t = repr(fn(float(t)))
        out.append(f"{t},{rest}")
    return out


@pytest.mark.parametrize("stamp", ["1e20", "1e300", "560000", "-1e9"])
def test_a_wild_stamp_is_dropped_and_nothing_else_is_lost(reference, stamp):
    lines = LINES[:]
    i = [k for k, ln in enumerate(lines) if ",uwb," in ln][500]
    lines[i] = stamp + lines[i][lines[i].index(","):]
    s = _run(lines)
    uwb, ref = s["sensors"]["uwb"], reference["sensors"]["uwb"]
    assert uwb["malformed"] == 1 and uwb["late"] == 0 and uwb["used"] == ref["used"] - 1
    assert s["events"]["time"] == 1
    assert s["errors"]["position_rmse_m"] == pytest.approx(reference["errors"]["position_rmse_m"], rel=0.05)


def test_the_whole_recording_jumping_a_million_seconds_is_resynchronised(reference):
    s = _run(_retime(LINES, lambda t: t + 1e6 if t > 30.0 else t))
    assert s["events"]["clock"] >= 1 and s["sensors"]["uwb"]["used"] >= reference["sensors"]["uwb"]["used"] - 3
    assert s["errors"]["position_rmse_m"] < 1.2 * reference["errors"]["position_rmse_m"]
    assert s["errors"]["samples"] > 0.95 * reference["errors"]["samples"]  # truth moved with it


def test_a_pause_shorter_than_max_predict_is_a_gap_predicted_over(reference):
    s = _run(_retime(LINES, lambda t: t + 20.0 if t > 30.0 else t))
    assert s["events"]["clock"] == 1            # reported ("taken as a gap"), and not re-timed:
    assert s["sensors"]["uwb"]["used"] >= reference["sensors"]["uwb"]["used"] - 3
    assert s["duration_s"] == pytest.approx(reference["duration_s"] + 20.0, abs=0.1)


def test_one_sensor_restarting_at_zero_is_resynchronised_abps():
    """Issue 10: "a sensor clock reset to 0 drops everything after it as late" (the ABPS ranges)."""
    lines = (ROOT / "recordings" / "abps_mine.log").read_text().splitlines()
    ref = _run(lines, ABPS)
    s = _run(_retime(lines, lambda t: t - 60.0 if t > 60.0 else t, sensors={"abps"}), ABPS)
    assert s["events"]["clock"] == 1
    assert s["sensors"]["abps"]["late"] <= ref["sensors"]["abps"]["late"] + 3
    assert s["sensors"]["imu"]["used"] == ref["sensors"]["imu"]["used"]
    assert s["errors"]["position_rmse_m"] < 0.10


def test_guard_rules_on_purpose_built_streams():
    g = ClockGuard(future_s=5.0, agree=3)
    m = lambda t: Message(t, "a", (1.0,))
    assert g.admit("a", m(0.0), 0.0, -float("inf"))[0][0][1] == 0.0
    out, ev = g.admit("a", m(1e9), 1e9, 0.1)              # held, never fed
    assert out == [] and ev == [] and g.busy
    out, ev = g.admit("a", m(0.2), 0.2, 0.1)              # back on the base: the held one was wild
    assert [t for _, t in out] == [0.2] and ev[0].kind == "time"
    # another sensor keeps the base alive while "b" jumps +100 s: b is re-synchronised
    for k in range(3):
        g.admit("a", m(0.3 + 0.1 * k), 0.3 + 0.1 * k, 0.3 + 0.1 * k)
        out, ev = g.admit("b", Message(100.3 + 0.1 * k, "b", (1.0,)), 100.3 + 0.1 * k, 0.3 + 0.1 * k)
    assert ev[0].kind == "clock" and "+100.000 s" in ev[0].detail
    assert [round(t, 9) for _, t in out] == [0.3, 0.4, 0.5]
    out, _ = g.admit("b", Message(100.6, "b", (1.0,)), 100.6, 0.55)
    assert out[0][1] == pytest.approx(0.6)


def test_cli_never_exits_1_on_stamps(tmp_path):
    lines = LINES[:]
    lines.insert(200, "1e308,uwb,B1,5.0")
    lines.insert(300, "inf,uwb,B1,5.0")
    lines.insert(400, "-0.0,uwb,B2,5.0")
    log = tmp_path / "x.log"
    log.write_text("\n".join(lines) + "\n")
    out = tmp_path / "s.json"
    assert main(["run", str(EXAMPLE), "--input", str(log), "-q", "--summary-json", str(out)]) == 0
    s = json.loads(out.read_text())
    assert s["sensors"]["uwb"]["malformed"] >= 2 and s["errors"]["position_rmse_m"] < 0.2


def test_a_plugin_failing_on_one_message_is_counted_and_the_run_goes_on(reference, monkeypatch):
    """Issue 10 item 1: an unknown beacon used to end the run with exit 1; whatever a plugin raises on one
    message, that message is malformed and the rest is used."""
    from fusion_plugins.measurement.range import RangeModel as RangeMeasurement

    real = RangeMeasurement.observe
    calls = {"n": 0}

    def flaky(self, message):
        calls["n"] += 1
        if calls["n"] == 700:
            raise KeyError("B9")
        return real(self, message)

    monkeypatch.setattr(RangeMeasurement, "observe", flaky)
    s = _run(LINES)
    uwb, ref = s["sensors"]["uwb"], reference["sensors"]["uwb"]
    assert uwb["malformed"] == 1 and uwb["used"] == ref["used"] - 1 and s["events"]["malformed"] == 1
