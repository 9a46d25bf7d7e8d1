"""Health: rates against expected rates, time since the last accepted measurement against its limit,
the overall OK/DEGRADED/LOST with its reason; on synthetic streams of known rates and in a replay."""
import asyncio
import math
import time
from pathlib import Path

import numpy as np
import pytest

from fusion.api import Belief, Estimate, Event, Message, UpdateResult
from fusion.tui.app import make_app
from fusion.tui.health import HealthMonitor
from fusion.tui.health_panel import HealthPanel
from fusion.tui.status_line import StatusLine

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"
RECORDING = ROOT / "recordings" / "example_2d.log"


def feed(mon, sensor, times, accepted=True):
    belief = Belief(0.0, np.zeros(2), np.eye(2))
    for t in times:
        mon.on_message(Message(t, sensor, ("1",)))
        if mon.roles[sensor] == "measurement":
            up = UpdateResult(belief, np.zeros(1), np.eye(1), 0.5, accepted)
            mon.on_estimate(Estimate(t, belief, "update", sensor, up))


def assess(mon, t, **kw):
    return mon.assess(t, mon.rates(t), {}, "running", **kw)


def test_rates_are_learned_then_a_slow_sensor_degrades_the_run():
    rng = np.random.default_rng(1)
    mon = HealthMonitor({"uwb": "measurement", "imu": "input"})
    t_uwb = np.arange(0.0, 10.0, 1 / 40) + rng.uniform(0, 1e-3, 400)  # 40 Hz with jitter
    t_imu = np.arange(0.0, 10.0, 1 / 100)
    feed(mon, "uwb", t_uwb)
    feed(mon, "imu", t_imu)
    h = assess(mon, 10.0)
    rows = {s.name: s for s in h.sensors}
    assert rows["uwb"].expected == pytest.approx(40.0, rel=0.01)   # learned over the first 5 s
    assert rows["imu"].expected == pytest.approx(100.0, rel=0.01)
    assert rows["uwb"].rate == pytest.approx(40.0, rel=0.02)       # the last 2 s
    assert rows["uwb"].limit == 1.0 and rows["imu"].limit == 1.0   # max(1 s, 10 / rate)
    assert h.state == "OK" and all(s.status == "ok" for s in h.sensors)
    # uwb drops to 10 Hz: under half its expected rate
    feed(mon, "uwb", np.arange(10.0, 14.0, 1 / 10))
    feed(mon, "imu", np.arange(10.0, 14.0, 1 / 100))
    h = assess(mon, 13.95)
    rows = {s.name: s for s in h.sensors}
    assert rows["uwb"].rate == pytest.approx(10.0, rel=0.06) and rows["uwb"].status == "slow"
    assert h.state == "DEGRADED" and h.reason.startswith("uwb: 10.")
    assert "of 40.0 expected" in h.reason


def test_time_since_accepted_beyond_the_limit_degrades_and_all_stale_is_lost():
    mon = HealthMonitor({"a": "measurement", "b": "measurement"}, expected={"a": 10.0, "b": 10.0}, limits={"b": 0.5})
    feed(mon, "a", np.arange(0.0, 5.0, 0.1))
    feed(mon, "b", np.arange(0.0, 5.0, 0.1))
    feed(mon, "b", np.arange(5.0, 7.0, 0.1), accepted=False)  # b's updates are all rejected from t = 5
    feed(mon, "a", np.arange(5.0, 7.0, 0.1))
    h = assess(mon, 6.9)
    rows = {s.name: s for s in h.sensors}
    last_b = np.arange(0.0, 5.0, 0.1)[-1]
    assert rows["b"].since_ok == pytest.approx(6.9 - last_b) and rows["b"].limit == 0.5
    assert rows["b"].status == "stale" and rows["a"].status == "ok"
    assert h.state == "DEGRADED" and h.reason == f"b: {6.9 - last_b:.1f} s without an accepted measurement (limit 0.5 s)"
    h = assess(mon, 8.5)  # nothing from either for 1.6 s: a beyond its 1 s limit too
    assert h.state == "LOST" and "no sensor within its limit" in h.reason


def test_source_state_nonfinite_estimate_and_filter_events():
    mon = HealthMonitor({"a": "measurement"}, expected={"a": 10.0})
    feed(mon, "a", np.arange(0.0, 2.0, 0.1))
    assert assess(mon, 1.95).state == "OK"
    assert mon.assess(1.95, {}, {}, "reconnecting", message="attempt 3: port lost").state == "LOST"
    lost = mon.assess(1.95, {}, {}, "lost", message="lost /dev/ttyUSB0: Input/output error")
    assert (lost.state, lost.reason) == ("LOST", "lost /dev/ttyUSB0: Input/output error")
    silent = mon.assess(1.95, {}, {}, "running", live=True, silent_wall_s=6.0)
    assert silent.state == "LOST" and silent.reason == "no data for 6 s"
    bad = Estimate(1.9, Belief(1.9, np.array([np.nan, 0.0]), np.eye(2)), "update", "a")
    assert assess(mon, 1.95, estimate=bad).reason == "estimate not finite"
    mon.on_event(Event(1.5, "not_positive_definite", None, "repaired"))
    mon.on_event(Event(1.6, "gap", "a", "gap"))
    h = assess(mon, 1.95, repairs=1)
    assert h.state == "DEGRADED" and "covariance repaired at t = 1.500" in h.reason and h.repairs == 1
    assert {s.name: s.counts["gap"] for s in h.sensors} == {"a": 1}
    feed(mon, "a", np.arange(2.0, 12.0, 0.1))
    assert assess(mon, 11.9).state == "OK"  # a repair degrades the run for recent_s = 10 s only


def test_replay_with_a_dropout_shows_degraded_with_its_reason():
    """uwb lines between 20 s and 25 s removed: at 24 s the view says DEGRADED, uwb ~4 s since accepted."""
    lines = RECORDING.read_text().splitlines(True)
    kept, last_before = [], None
    for line in lines:
        head = line.split(",", 2)
        if len(head) > 2 and head[1] == "uwb":
            t = float(head[0])
            if 20.0 <= t < 25.0:
                continue
            if t < 20.0:
                last_before = t
        kept.append(line)

    async def drive(path):
        app = make_app(CONFIG, path, speed=0, pause_at=24.0)
        async with app.run_test(size=(120, 40)) as pilot:
            deadline = time.monotonic() + 20
            while not (app.feed.paused and app.latest is not None and app.latest.health is not None
                       and app.latest.sensor_t >= 24.0):
                assert time.monotonic() < deadline
                await pilot.pause(0.02)
            await pilot.pause(0.1)
            snap = app.latest
            row = {s.name: s for s in snap.health.sensors}["uwb"]
            # The last uwb line before the dropout may still sit in the reorder buffer (max_latency 0.05 s):
            # the last accepted update is one of the last two before 20 s.
            assert 24.0 <= snap.sensor_t < 24.2 and last_before - 0.05 <= snap.estimate.t <= last_before
            assert row.since_ok == pytest.approx(snap.sensor_t - snap.estimate.t, abs=1e-9) and row.since_ok > 4.0
            assert snap.health.state in ("DEGRADED", "LOST")
            assert "uwb" in snap.health.reason and "without an accepted" in snap.health.reason
            assert app.query_one(HealthPanel).rows["uwb"][-1] == "stale"
            assert snap.health.state in app.query_one(StatusLine).text
            await pilot.press("q")

    import tempfile
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "dropout.log"
        path.write_text("".join(kept))
        asyncio.run(drive(path))
