"""A replay in the live view is paced by the stream's time as the scheduler keeps it (after the clock
guard), not by raw stamps: one wild stamp that the guard drops does not freeze the view (a
stamp 100,000 s ahead would hold it for (100000 - 5) / speed seconds), and no single wait is longer than
``scheduler.max_predict_s`` / speed. The clock is virtual: waits are measured exactly, without waiting."""
from pathlib import Path

import pytest

from fusion.config import load_system
from fusion.tui.feed import LiveFeed

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"


class VirtualClock:
    """Stands in for the feed's ``time`` module: sleep() advances monotonic() at once."""

    def __init__(self):
        self.now, self.slept = 1000.0, 0.0

    def monotonic(self):
        return self.now

    def sleep(self, dt):
        self.now += dt
        self.slept += dt


def _lines(n, dt=0.05, start=0.0):
    return [f"{start + i * dt:.3f},uwb,B{i % 4 + 1},{10.0 + 0.01 * i}\n" for i in range(n)]


def _run(monkeypatch, lines, speed=4.0):
    import fusion.tui.feed as feed_mod

    clock = VirtualClock()
    monkeypatch.setattr(feed_mod, "time", clock)
    feed = LiveFeed(load_system(CONFIG), lines, lambda s: None, speed=speed)
    return feed.run(), clock


@pytest.mark.parametrize("wild", [100000.0, 1e12, -50.0])
def test_a_wild_stamp_is_not_waited_for(monkeypatch, wild):
    lines = _lines(200)                                          # 0 .. 9.95 s of sensor time
    lines.insert(101, f"{wild:.6f},uwb,B1,4.2\n")                 # after t = 5.0 s
    final, clock = _run(monkeypatch, lines)
    assert final.state == "finished" and final.counters["uwb"]["received"] == 201
    assert final.estimate.t == pytest.approx(9.95)
    assert clock.slept == pytest.approx(9.95 / 4.0, abs=0.02)    # the sensor time's span at 4x, nothing more
    assert not [e for e in final.events if e.kind == "replay"]


def test_a_wild_first_stamp_does_not_stop_the_pacing(monkeypatch):
    lines = _lines(200)
    lines.insert(1, "100000.000000,uwb,B1,4.2\n")
    final, clock = _run(monkeypatch, lines)
    assert final.state == "finished"
    assert clock.slept == pytest.approx(9.95 / 4.0, abs=0.1)     # paced (not as fast as possible), never frozen


@pytest.mark.parametrize("gap, waited", [(30.0, 30.0), (1000.0, 60.0)])
def test_a_pause_of_the_stream_is_waited_for_as_the_scheduler_takes_it(monkeypatch, gap, waited):
    """The stream moves on over a pause of every stream, however long (fusion.clock keeps its stamps):
    waited for at speed, at most scheduler.max_predict_s (60 s here) / speed, the longest gap the scheduler
    predicts over. (The cap used to move the pacing's origin the wrong way: 1000 s waited as 1940 s.)"""
    lines = _lines(40) + _lines(40, start=1.95 + gap)
    final, clock = _run(monkeypatch, lines, speed=2.0)
    assert final.state == "finished" and final.counters["uwb"]["received"] == 80
    assert clock.slept == pytest.approx((1.95 + waited + 1.95) / 2.0, abs=0.1)
