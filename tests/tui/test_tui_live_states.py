"""What a live view says about its port (issue 28 item 3), on a virtual clock (exact, nothing waits):
a port silent since it was opened is LOST (docs/tui.md), not WAITING OK; after a replug the lag is
measured afresh, so "BEHIND by 34.4 s" does not stay once everything sent has been read."""
import math
from pathlib import Path

import pytest

from fusion.config import load_system
from fusion.tui.feed import LiveFeed
from fusion.tui.status_line import describe
from virtual_clock import clock  # noqa: F401  (the fixture)

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"
DT = 0.05  # s of sensor time between lines


def test_a_port_silent_since_it_was_opened_is_lost(clock):
    snaps, box = [], []

    def silent_port():   # read timeouts of 0.1 s for 8 s, each reported as a serial source does (on_idle)
        for _ in range(80):
            clock.now += 0.1
            box[0].idle()
        return
        yield

    feed = LiveFeed(load_system(CONFIG), silent_port(), snaps.append, live=True)
    box.append(feed)
    feed.run()
    during = [s for s in snaps if s.state != "finished"]
    last = during[-1]                              # not only the first snapshot, "waiting" and OK
    assert last.wall - 1000.0 >= 7.0
    assert last.health.state == "LOST" and last.health.reason.startswith("no data for")
    line = describe(last, False, "ukf", last.wall).plain
    assert " LOST  no data for" in line, line
    early = [s for s in during if s.wall - 1000.0 < 4.0]
    assert early and all(s.health.state == "OK" for s in early)   # not before silent_s (5 s)


def test_after_a_replug_the_lag_restarts_from_the_reopened_port(clock):
    snaps, box = [], []

    def replugged():
        for i in range(200):          # read as fast as it is sent: no lag
            clock.now += DT
            yield f"{i * DT:.3f},uwb,B{i % 4 + 1},{10.0 + 0.01 * i}\n"
        feed = box[0]
        feed.source_status("reconnecting", 1, "Input/output error")
        clock.now += 34.4              # unplugged; the device's clock stopped meanwhile (powered by the port)
        feed.source_status("connected", 1, "")
        for i in range(200, 400):     # its stamps go on from where they stopped, read as they come
            clock.now += DT
            yield f"{i * DT:.3f},uwb,B{i % 4 + 1},{10.0 + 0.01 * i}\n"

    feed = LiveFeed(load_system(CONFIG), replugged(), snaps.append, live=True)
    box.append(feed)
    feed.run()
    after = [s.lag_s for s in snaps if s.state == "running" and s.lines > 210 and not math.isnan(s.lag_s)]
    assert after and max(after) == pytest.approx(0.0, abs=1e-6)   # not 34.4 to the end
    assert all("BEHIND" not in describe(s, False, "ukf", s.wall).plain for s in snaps if s.lines > 210)
