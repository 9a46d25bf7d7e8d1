"""ABPS after a logger blackout: every sensor silent for 8 s while the vehicle drives on. The belief comes
back metres and m/s off; its velocity spoils the motion compensation of the fixes, so every cycle could
be refused as inconsistent for the rest of the run (the fix that would correct the belief refused because
of the belief: not one estimate after the gap). After three cycles refused in a row, a cycle is
solved without the belief."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fusion import pipeline
from fusion.config import load_system
from fusion.testing.faults import cut_recording

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "abps_ins.yaml"


def _lines(cut=None, end=80.0):
    return cut_recording(ROOT / "recordings" / "abps_mine.log",
                         None if cut is None else lambda t, ln: cut[0] < t < cut[1], end=end)


def _run_cut(config: Path):
    events, estimates = [], []

    class Keep:
        def on_estimate(self, e):
            estimates.append(e)

        def close(self):
            pass

    pipeline.run(load_system(config), _lines(cut=(50.0, 58.0)), [Keep()], on_event=events.append)
    updates = np.array([e.t for e in estimates if e.reason == "update" and e.sensor == "abps"])
    return events, updates[updates > 58.0]


def test_fixes_are_used_at_once_after_a_blackout():
    """Past hold_after the state coasts (the last IMU sample is not integrated over the 8 s),
    so the belief comes back near enough for the first cycle's fix to be accepted: no cycle refused."""
    events, after = _run_cut(CONFIG)
    assert after.size >= 40 and after[0] < 58.5
    assert not [e for e in events if e.kind == "reacquired"]


def test_fixes_come_back_within_a_few_cycles_after_a_blackout(tmp_path):
    """The sample held over the whole blackout (no hold_after): the belief comes back metres and m/s off,
    and the reacquire solves a cycle without it."""
    text = CONFIG.read_text()
    assert "  hold_after: 0.015" in text
    config = tmp_path / "held.yaml"
    config.write_text(text.replace("  hold_after: 0.015", "  # hold_after: 0.015").replace(
        "recording: ../recordings/", f"recording: {ROOT / 'recordings'}/"))
    events, after = _run_cut(config)
    back = [e for e in events if e.kind == "reacquired"]
    assert back and 58.0 < back[0].t < 61.0, [(e.t, e.detail) for e in back[:3]]
    assert after.size >= 40                                       # fixes go on being used to the end (80 s)
    assert all("cycles refused in a row" in e.detail for e in back)


def test_no_reacquiring_on_the_uncut_recording():
    events = []
    pipeline.run(load_system(CONFIG), _lines(), on_event=events.append)
    assert not [e for e in events if e.kind == "reacquired"]


def test_an_input_that_dies_is_reported_once_while_the_others_go_on():
    """The IMU stops at 40 s, the ranges go on to 60 s: one gap event (not one that waits for the next sample,
    which never comes)."""
    lines = [ln for ln in _lines(end=60.0) if not (",imu," in ln and float(ln.split(",", 1)[0]) > 40.0)]
    events = []
    pipeline.run(load_system(CONFIG), lines, on_event=events.append)
    gaps = [e for e in events if e.kind == "gap" and e.sensor == "imu"]
    assert len(gaps) == 1 and "while abps goes on" in gaps[0].detail and 40.05 < gaps[0].t < 40.5


def test_a_healthy_input_is_never_reported():
    events = []
    pipeline.run(load_system(CONFIG), _lines(end=40.0), on_event=events.append)
    assert not [e for e in events if e.kind == "gap"]
