"""The parts of the live view without a screen: state rows (units, attitude in degrees), the braille canvas,
the track plot's drawing, and the feed's pacing, coalescing and pause semantics."""
import math
import time
from pathlib import Path

import numpy as np
import pytest

from fusion import quaternion
from fusion.api import Belief, StateLayout
from fusion.config import load_system
from fusion.tui.canvas import BrailleCanvas
from fusion.tui.feed import LiveFeed
from fusion.tui.state_rows import euler_deg, fmt_sd, fmt_value, state_rows
from fusion.tui.track_plot import TrackPlot, _scale_bar

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"


def test_state_rows_show_attitude_in_degrees_with_sigma_along_yaw():
    lay = StateLayout.parse("p:3 v:3 q:4 ba:3 bw:3")
    roll, pitch, yaw = np.radians([10.0, -20.0, 135.0])
    q = quaternion.from_euler(roll, pitch, yaw)
    # Covariance of a pure yaw uncertainty of 2 deg: P_q = g g^T sigma^2 with g = dq/dyaw.
    h = 1e-7
    g = (quaternion.from_euler(roll, pitch, yaw + h) - quaternion.from_euler(roll, pitch, yaw - h)) / (2 * h)
    P = np.eye(16) * 1e-4
    P[6:10, 6:10] = np.outer(g, g) * np.radians(2.0) ** 2
    x = np.concatenate([[1, 2, 3], [0.1, 0.2, 0.3], q, [0.01, 0.02, 0.03], np.radians([0.1, 0.2, 0.3])])
    rows = {r.key: r for r in state_rows(lay, Belief(0.0, x, P=P))}
    assert list(rows) == ["px", "py", "pz", "vx", "vy", "vz", "roll", "pitch", "yaw",
                          "bax", "bay", "baz", "bwx", "bwy", "bwz"]
    assert rows["roll"].value == pytest.approx(10.0) and rows["pitch"].value == pytest.approx(-20.0)
    assert rows["yaw"].value == pytest.approx(135.0)
    assert rows["yaw"].sd == pytest.approx(2.0, rel=1e-4)
    assert rows["roll"].sd == pytest.approx(0.0, abs=1e-4) and rows["pitch"].sd == pytest.approx(0.0, abs=1e-4)
    assert rows["yaw"].unit == "deg" and rows["px"].unit == "m" and rows["vz"].unit == "m/s"
    assert rows["bax"].unit == "m/s^2" and rows["bwz"].unit == "deg/s"
    assert rows["bwz"].value == pytest.approx(0.3) and rows["bwz"].sd == pytest.approx(math.degrees(1e-2))
    assert rows["pz"].sd == pytest.approx(1e-2)


def test_euler_sigma_is_continuous_across_the_yaw_wrap():
    q = quaternion.from_euler(0.0, 0.0, math.pi)  # yaw at +-180 deg
    angles, sd = euler_deg(q, np.eye(4) * 1e-6)
    assert abs(abs(angles[2]) - 180.0) < 1e-9
    assert np.all(sd < 1.0)


def test_angle_blocks_and_formats():
    lay = StateLayout.parse("psi:1:angle")
    rows = state_rows(lay, Belief(0.0, np.array([math.pi / 2]), P=np.array([[0.01]])))
    assert rows[0].key == "psi" and rows[0].unit == "deg" and rows[0].value == pytest.approx(90.0)
    assert fmt_value(-0.17005663) == "-0.1701" and fmt_value(1.5e7) == "1.5e+07"
    assert fmt_sd(0.0702) == "0.0702" and fmt_sd(1.23e-5) == "1.23e-05"


def test_braille_canvas_dots_lines_and_labels():
    c = BrailleCanvas(3, 1)
    c.dots(np.array([0, 1, 5]), np.array([0, 3, 0]), style="red")
    assert c.render().plain == "⢁ ⠈"
    c = BrailleCanvas(2, 1)
    c.polyline(np.array([0.0, 3.0]), np.array([0.0, 0.0]))
    assert c.render().plain == "⠉⠉"
    c.text(2, 0, "A", style="bold")
    text = c.render()
    assert text.plain == "⠉A"
    assert any(str(span.style) == "bold" for span in text.spans)
    c = BrailleCanvas(2, 2)
    c.dots(np.array([-1, 99]), np.array([0, 0]))  # outside: ignored
    assert c.render().plain == "  \n  "


def test_track_plot_draws_north_up_east_right_with_equal_scales():
    plot = TrackPlot(beacons={"A": [0.0, 0.0], "B": [0.0, 10.0], "C": [10.0, 0.0]})
    plot.track = np.array([[0.0, 0.0], [10.0, 10.0]])
    plot.current = (10.0, 10.0)
    lines = plot.draw(40, 12).plain.splitlines()
    assert len(lines) == 12 and "(east →, north ↑)" in lines[-1]
    row_of = {name: next(i for i, line in enumerate(lines) if "▲" + name in line) for name in "ABC"}
    col_of = {name: lines[row_of[name]].index("▲" + name) for name in "ABC"}
    assert row_of["C"] < row_of["A"] == row_of["B"]  # north (C) is up
    assert col_of["B"] > col_of["A"] == col_of["C"]  # east (B) is right
    # 10 m east spans as many dots as 10 m north (a cell is 2 dots wide, 4 tall).
    assert 2 * (col_of["B"] - col_of["A"]) == pytest.approx(4 * (row_of["A"] - row_of["C"]), abs=2)
    assert "●" in lines[row_of["C"]]
    # 40 cells = 80 dots; at 2 dots/m a quarter of the width is 10 m = 10 cells.
    assert _scale_bar(2.0, 40).startswith("├────────┤ 10 m ")


def _lines(n, dt=0.05):
    head = ["# fields uwb beacon range\n"]
    return head + [f"{i * dt:.3f},uwb,B{i % 4 + 1},{10.0 + 0.01 * i}\n" for i in range(n)]


class VirtualClock:
    """Stands in for the feed's ``time`` module: sleep() advances monotonic() instantly, so pacing is
    checked exactly and without waiting."""

    def __init__(self):
        self.now = 1000.0
        self.slept = 0.0

    def monotonic(self):
        return self.now

    def sleep(self, dt):
        self.now += dt
        self.slept += dt


def test_replay_is_paced_by_sensor_time_and_snapshots_are_coalesced(monkeypatch):
    import fusion.tui.feed as feed_mod

    clock = VirtualClock()
    monkeypatch.setattr(feed_mod, "time", clock)
    snaps = []
    feed = LiveFeed(load_system(CONFIG), _lines(21), snaps.append, source="test", speed=4.0, refresh_hz=20)
    final = feed.run()
    assert final.state == "finished" and final.lines == 22
    # 1 s of sensor time at 4x real time: the feed waits 1/4 s in all (in slices), no more.
    assert clock.slept == pytest.approx(0.25, abs=0.01)
    assert final.counters["uwb"]["received"] == 21
    assert len(snaps) <= clock.slept * 20 + 4  # at most refresh_hz snapshots a second (+ first, pause, last)

    snaps.clear()
    clock.slept = 0.0
    fast = LiveFeed(load_system(CONFIG), _lines(400), snaps.append, speed=0.0, refresh_hz=10)
    fast.run()
    assert clock.slept == 0.0  # speed 0: 20 s of sensor time, never paced
    assert snaps[-1].state == "finished" and len(snaps) < 400 / 10  # coalesced, not one per line


def test_pausing_a_live_feed_freezes_only_the_view(monkeypatch):
    import fusion.tui.feed as feed_mod

    clock = VirtualClock()
    monkeypatch.setattr(feed_mod, "time", clock)
    held = []
    feed = LiveFeed(load_system(CONFIG), _lines(50), lambda s: None, live=True, speed=1.0)
    monkeypatch.setattr(feed, "_hold", lambda: held.append(1) or 0.0)
    feed.pause()
    final = feed.run()
    # a live source is read on while paused: never held, never paced, every line through
    assert final.state == "finished" and final.lines == 51 and final.counters["uwb"]["received"] == 50
    assert held == [] and clock.slept == 0.0


def test_stop_ends_a_paused_replay():
    import threading

    holding = threading.Event()
    # the feed posts a snapshot when it starts holding a paused replay (after its first line)
    feed = LiveFeed(load_system(CONFIG), _lines(100), lambda s: holding.set() if s.lines else None, speed=1.0)
    feed.pause()
    done = []
    worker = threading.Thread(target=lambda: done.append(feed.run()))
    worker.start()
    assert holding.wait(60.0)  # hang guard only
    assert not done            # held: nothing but stop() or resume() lets it on
    feed.stop()
    worker.join(60.0)
    assert done and done[0].state == "stopped" and done[0].lines <= 2
