"""A live view that cannot keep up with its device says so (a 1 kHz IMU can leave the view minutes
behind): ``FeedSnapshot.lag_s`` is how far the wall clock has got ahead of the
stream's time beyond its least so far, and the status line shows ``BEHIND by N s``. The feed's clock is
virtual: a line "takes" a set wall time, so the lag is exact and nothing waits."""
import asyncio
import math
import threading
import time
from pathlib import Path

import pytest

from fusion.api import Params, Source
from fusion.config import load_system
from fusion.tui.app import make_app
from fusion.tui.feed import LiveFeed
from fusion.tui.status_line import StatusLine, describe
from virtual_clock import VirtualClock

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"
DT = 0.05  # s of sensor time between lines


def device(clock, n, wall_per_line, hold: threading.Event | None = None):
    """n lines DT apart in sensor time, each read ``wall_per_line`` s after the previous one; then (with
    ``hold``) a port that stays open, silent, until ``hold`` is set."""
    for i in range(n):
        clock.now += wall_per_line
        yield f"{i * DT:.3f},uwb,B{i % 4 + 1},{10.0 + 0.01 * i}\n"
    if hold is not None:
        hold.wait(30.0)


def running_lags(monkeypatch, wall_per_line):
    import fusion.tui.feed as feed_mod

    clock = VirtualClock()
    monkeypatch.setattr(feed_mod, "time", clock)
    snaps = []
    LiveFeed(load_system(CONFIG), device(clock, 400, wall_per_line), snaps.append, live=True).run()
    return [s.lag_s for s in snaps if s.state == "running" and s.lag_s == s.lag_s]


def test_a_view_that_keeps_up_has_no_lag(monkeypatch):
    lags = running_lags(monkeypatch, DT)
    assert lags and max(lags) == pytest.approx(0.0, abs=1e-6)


def test_a_view_at_half_the_device_rate_falls_behind_by_what_it_did_not_read(monkeypatch):
    lags = running_lags(monkeypatch, 2 * DT)   # each line read 2 DT after the last: half the device's pace
    assert lags == sorted(lags)
    assert lags[-1] == pytest.approx(400 * DT, abs=0.3)   # 20 s of data read in 40 s: 20 s behind


def test_a_replay_has_no_lag():
    snaps = []
    LiveFeed(load_system(CONFIG), [f"{i * DT:.3f},uwb,B1,10\n" for i in range(50)], snaps.append, speed=0.0).run()
    assert all(math.isnan(s.lag_s) for s in snaps)


class SlowDevice(Source):
    """A live source whose lines come at half the pace the view reads them (on the virtual clock)."""

    name = "slow-device"
    live = True

    class Params(Params):
        port: str = "test"

    def __init__(self, clock):
        super().__init__(self.Params())
        self.clock, self.hold = clock, threading.Event()

    def lines(self):
        return device(self.clock, 300, 2 * DT, self.hold)

    def close(self):
        self.hold.set()


def test_the_status_line_says_how_far_behind_the_view_is(monkeypatch):
    import fusion.tui.feed as feed_mod

    clock = VirtualClock()
    monkeypatch.setattr(feed_mod, "time", clock)
    source = SlowDevice(clock)

    async def drive():
        app = make_app(CONFIG, source)
        async with app.run_test(size=(140, 40)) as pilot:
            deadline = time.monotonic() + 20
            while not (app.latest is not None and app.latest.lines >= 300):
                assert time.monotonic() < deadline   # a hang guard, not a timing
                await pilot.pause(0.02)
            await pilot.pause(0.1)
            text = app.query_one(StatusLine).text
            snap = app.latest
            assert snap.state == "running" and snap.lag_s > 10.0
            assert f"BEHIND by {snap.lag_s:.1f} s" in text
            await pilot.press("q")
        source.hold.set()

    asyncio.run(drive())


def test_no_behind_part_while_caught_up_or_replaying(monkeypatch):
    snaps = []
    LiveFeed(load_system(CONFIG), [f"{i * DT:.3f},uwb,B1,10\n" for i in range(20)], snaps.append, speed=0.0).run()
    for snap in snaps:
        assert "BEHIND" not in describe(snap, False, "ukf", time.monotonic()).plain
