"""The live view driven headless (App.run_test + pilot): replay equals `fusion run`, counters, keys."""
import asyncio
import re
import time
from pathlib import Path

import numpy as np

from fusion import pipeline
from fusion.config import load_system
from fusion.tui.app import make_app
from fusion.tui.counters import SensorCounters
from fusion.tui.event_log import EventLog
from fusion.tui.state_table import StateTable
from fusion.tui.status_line import StatusLine
from fusion.tui.track_plot import TrackPlot

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"
RECORDING = ROOT / "recordings" / "example_2d.log"
SIZE = (130, 40)
DONE = ("finished", "lost", "error", "stopped")


async def until(pilot, cond, timeout=15.0, what="condition"):
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        await pilot.pause(0.02)


def finished(app):
    return app.latest is not None and app.latest.state in DONE


def reference(source=None):
    system = load_system(CONFIG)
    src = source or system.recording
    kept = pipeline.Collect()
    result = pipeline.run(system, src, [kept])
    return {"estimates": kept.estimates}, result.summary


def test_replay_at_speed_0_shows_the_final_estimate_of_fusion_run():
    result, summary = reference()
    final = result["estimates"][-1]

    async def drive():
        app = make_app(CONFIG, speed=0)
        async with app.run_test(size=SIZE) as pilot:
            await until(pilot, lambda: finished(app), what="the end of the replay")
            await pilot.pause(0.05)
            snap = app.latest
            assert snap.state == "finished"
            # The estimate the view holds is the very last one `fusion run` computes.
            assert snap.estimate.t == final.t
            np.testing.assert_array_equal(snap.estimate.belief.x, final.belief.x)
            table = app.query_one(StateTable)
            sd = np.sqrt(np.diag(final.belief.P))
            for i, name in enumerate(("px", "py", "vx", "vy")):
                value, sigma, unit = table.cells[name]
                assert abs(float(value) - final.belief.x[i]) <= 5e-5
                assert abs(float(sigma) - sd[i]) <= 5e-3 * sd[i]
                assert unit == ("m" if name.startswith("p") else "m/s")
            assert f"t = {final.t:.3f} s" in table.border_title
            # Counters as `fusion run` reports them, in the widget too.
            counters = app.query_one(SensorCounters)
            assert snap.counters == summary["sensors"]
            assert counters.values == summary["sensors"]
            row = counters.cells["uwb"]
            assert row[:6] == ("uwb", *(str(summary["sensors"]["uwb"][k]) for k in
                                        ("received", "used", "rejected", "malformed", "late")))
            assert re.search(r"^uwb +2684 +2684 +0 +0 +0 +40\.\d$", str(counters.render()), re.M)
            status = app.query_one(StatusLine).text
            assert "FINISHED" in status and "example_2d.log" in status and "filter ukf" in status
            assert app.query_one(TrackPlot).points_shown > 100
            # 2684 estimates, but the UI got a coalesced snapshot stream (15 Hz over a ~1-3 s replay).
            assert len(result["estimates"]) > 2000
            assert app.updates < 200

    asyncio.run(drive())


def test_keys_pause_holds_the_replay_reset_clears_the_view_quit_stops(tmp_path):
    log = tmp_path / "bad.log"
    lines = RECORDING.read_text().splitlines()
    lines.insert(30, "0.6,uwb,B1,not-a-number")
    log.write_text("\n".join(lines) + "\n")

    async def drive():
        app = make_app(CONFIG, log, speed=4)
        async with app.run_test(size=SIZE) as pilot:
            plot, events, status = app.query_one(TrackPlot), app.query_one(EventLog), app.query_one(StatusLine)
            await until(pilot, lambda: plot.points_shown > 5 and events.lines_text, what="a trail and an event")
            # p: a replay stops reading; the view holds still.
            await pilot.press("p")
            assert app.paused and app.feed.paused
            await pilot.pause(0.1)
            held, shown = app.feed.lines_read, app.latest.sensor_t
            await pilot.pause(0.3)
            assert app.feed.lines_read == held and app.latest.sensor_t == shown
            assert "PAUSED" in status.text
            # r: the trail and the event log shown so far are forgotten.
            await pilot.press("r")
            assert plot.points_shown == 0 and not events.lines_text
            # p again: the replay goes on, the plot draws the new points only.
            await pilot.press("p")
            assert not app.paused
            await until(pilot, lambda: app.feed.lines_read > held + 20 and plot.points_shown > 3,
                        what="the replay to resume")
            assert plot.points_shown < app.latest.track_total
            assert "RUNNING" in status.text or finished(app)
            await pilot.press("q")
        assert app.feed.stopped

    asyncio.run(drive())


def test_quit_stops_the_reader_promptly():
    async def drive():
        app = make_app(CONFIG, speed=1)
        t0 = time.monotonic()
        async with app.run_test(size=SIZE) as pilot:
            await until(pilot, lambda: app.feed.lines_read > 5, what="the replay to start")
            await pilot.press("q")
        return app, time.monotonic() - t0

    app, _ = asyncio.run(drive())  # asyncio.run returns only once the worker thread has ended
    assert app.feed.stopped and app.feed.state == "stopped"


def test_malformed_lines_are_counted_and_logged_with_line_numbers(tmp_path):
    log = tmp_path / "bad.log"
    lines = RECORDING.read_text().splitlines()[:600]
    bad = {25: "0.5,uwb,B1,abc", 40: "garbage", 60: "1.0,sonar,3.0", 80: "1.2,uwb,B1,3.0*00"}
    for i in sorted(bad):
        lines.insert(i - 1, bad[i])  # so that the bad line is line i of the file
    log.write_text("\n".join(lines) + "\n")
    _, summary = reference(log)

    async def drive():
        app = make_app(CONFIG, log, speed=0)
        async with app.run_test(size=SIZE) as pilot:
            await until(pilot, lambda: finished(app), what="the end of the replay")
            await pilot.pause(0.05)
            assert app.latest.counters == summary["sensors"]
            text = "\n".join(app.query_one(EventLog).lines_text)
            for i in (25, 40, 80):
                assert f"line {i}:" in text
            assert "malformed" in text and "bad checksum" in text
            assert app.latest.ignored == {"sonar": 1}
            assert app.query_one(SensorCounters).cells["ignored:sonar"][0] == "sonar (not in config)"

    asyncio.run(drive())


def test_a_timer_tick_or_a_feed_update_without_a_screen_draws_nothing():
    """A tick of the half-second timer or a snapshot from the feed's thread can arrive when no screen is
    mounted (before the first, or during teardown: an IndexError once ended a test run); they are dropped."""
    from fusion.tui.messages import FeedUpdate

    app = make_app(CONFIG, speed=0)
    assert not app.screen_stack
    asyncio.run(app._tick())
    snap = app.feed._emit(time.monotonic())    # a real snapshot of the feed, before any line was read
    app.on_feed_update(FeedUpdate(snap))
    assert app.latest is snap and app.updates == 1
