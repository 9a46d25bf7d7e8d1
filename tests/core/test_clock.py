"""Time sanity (issue 10 item 2, fusion/run/clock.py): wild stamps never move the horizon, clock jumps and
restarts are detected and re-synchronised, gaps are bounded.

Every time asserted here is a sensor stamp of the recording (or the span they cover, ``duration_s``),
set by the test's own re-timing of the lines; nothing measures how long the code takes (speed is in
benchmarks/)."""
from __future__ import annotations

import json
import math
import random
from pathlib import Path

import pytest

from fusion import pipeline
from fusion.api import Message
from fusion.cli import main
from fusion.run.clock import ClockGuard
from fusion.config import SchedulerSpec, load_system

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


def test_the_whole_recording_jumping_a_million_seconds_is_a_gap_and_keeps_its_stamps(reference):
    """Every stream (truth too) jumping together is a pause of the recording, however long: there is no old
    time left to re-synchronise to (tester3 #2: a pause >= max_predict_s used to be renumbered, the output
    times fabricated). The prediction over it is bounded (scheduler.max_predict_s); every estimate with truth
    near it is scored."""
    s = _run(_retime(LINES, lambda t: t + 1e6 if t > 30.0 else t))
    assert s["events"]["clock"] == 1 and s["sensors"]["uwb"]["used"] == reference["sensors"]["uwb"]["used"]
    assert s["duration_s"] == pytest.approx(reference["duration_s"] + 1e6, abs=0.1)
    # all but the estimates in the truth's own gap (more than half a truth period from its next sample)
    assert s["errors"]["samples"] >= reference["errors"]["samples"] - 2
    assert s["errors"]["position_rmse_m"] < 10.0   # the track is found again after the bounded prediction


@pytest.mark.parametrize("pause", [8.0, 50.0, 60.5, 100.0])
def test_a_pause_of_every_stream_keeps_the_stamps_and_scores_every_estimate(pause):
    """tester3 #2 and #3: every stream (truth too) stops at 20 s and goes on ``pause`` s later (the lines from
    20 s on are stamped ``pause`` later: the walk goes on where it stopped). The stamps after it are kept
    (pauses from max_predict_s = 60 s on used to be re-synchronised: the output ended 60 s early, RMSE 337 m)
    and the first truth rows after it are compared (they were dropped as 'far from the stream's time', so
    the largest errors, right after the pause, were missing from the summary)."""
    lines = _retime(LINES, lambda t: t + pause if t >= 20.0 else t)
    system = load_system(EXAMPLE)
    from fusion.pipeline import Collect

    sink = Collect()
    s = pipeline.run(system, [ln + "\n" for ln in lines], [sink]).summary
    assert "time" not in s["events"]                     # nothing dropped as a wild stamp
    last = max(float(ln.split(",", 1)[0]) for ln in lines if not ln.startswith("#"))
    assert sink.estimates[-1].t == pytest.approx(last) and s["duration_s"] == pytest.approx(last, abs=1e-9)
    truth = {round(float(ln.split(",")[0]), 6) for ln in lines if ",truth," in ln}
    with_truth = sum(round(e.t, 6) in truth for e in sink.estimates)
    assert s["errors"]["samples"] >= with_truth           # every estimate at a truth stamp is scored
    uwb = s["sensors"]["uwb"]
    assert uwb["malformed"] == 0 and uwb["rejected"] <= 3


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


# ---------------------------------------------------------------- the cadence bound (inside future_s)

def _feed(stream, inputs=("imu",), **kw):
    """``(sensor, t)`` pairs through a ClockGuard driven as the scheduler drives it (``steady`` for the
    input sensors while nothing is held, else ``admit``; the stream's newest time is the newest fed
    stamp): returns what is fed, in order, as ``(sensor, t)``, and the events."""
    spec = SchedulerSpec()
    kw = dict(cadence_k=spec.cadence_k, cadence_floor_s=spec.cadence_floor_s) | kw
    g = ClockGuard(spec.future_s, spec.resync_after, sensors={s for s, _ in stream}, **kw)
    newest, fed, events = -math.inf, [], []
    for s, t in stream:
        if s in inputs and not g.busy and g.steady(s, t, newest):
            out, ev = [(Message(t, s, (1.0,)), t)], []
        else:
            out, ev = g.admit(s, Message(t, s, (1.0,)), t, newest)
        events += ev
        for m, tc in out:
            assert tc >= newest - 1e-12, f"{m.sensor} at {tc} fed behind the newest time {newest}: late"
            fed.append((m.sensor, tc))
            newest = max(newest, tc)
    for m, tc in g.release():
        fed.append((m.sensor, tc))
    return fed, events


def _merge(*streams):
    return sorted((p for s in streams for p in s), key=lambda p: p[1])


def _every(sensor, t0, t1, dt):
    return [(sensor, round(t0 + k * dt, 9)) for k in range(int(round((t1 - t0) / dt)))]


@pytest.mark.parametrize("ahead", [0.2, 1.0, 4.0])
def test_cadence_a_wild_stamp_ahead_inside_future_s_is_dropped_and_the_rest_fed(ahead):
    real = _merge(_every("imu", 0.0, 20.0, 0.01), _every("abps", 0.007, 20.0, 0.06))
    k = real.index(("abps", 0.007 + 0.06 * 150))
    wild = real[:k] + [("abps", real[k][1] + ahead)] + real[k + 1:]
    fed, events = _feed(wild)
    assert fed == real[:k] + real[k + 1:]                     # every other message, in order, none late
    assert [e.kind for e in events] == ["time"] and "dropped" in events[0].detail


def test_cadence_a_wild_stamp_of_a_lone_sensor_is_dropped():
    real = _every("uwb", 0.0, 10.0, 0.05)
    wild = real[:100] + [("uwb", real[100][1] + 1.0)] + real[101:]
    fed, events = _feed(wild)
    assert fed == real[:100] + real[101:] and [e.kind for e in events] == ["time"]


def test_cadence_start_up_a_wild_first_stamp_is_dropped_and_a_real_first_gap_kept():
    """The fuzz case of issue 10 item 9: the ABPS's first range stamped 1 s ahead, nothing learned yet."""
    real = _merge(_every("imu", 0.0, 5.0, 0.01), _every("abps", 0.007, 5.0, 0.06))
    k = real.index(("abps", 0.007))
    fed, events = _feed(real[:k] + [("abps", 1.007)] + real[k + 1:])
    assert fed == real[:k] + real[k + 1:] and [e.kind for e in events] == ["time"]
    # a sensor whose first messages come after a pause of the whole stream, and a slow lone sensor starting
    for stream in (_every("imu", 0.0, 0.05, 0.01) + _every("imu", 3.0, 5.0, 0.01),
                   _every("us", 0.1, 10.0, 0.225),
                   [("imu", 0.0), ("gps", 0.0)] + _merge(_every("imu", 0.01, 5.0, 0.01), _every("gps", 1.0, 5.0, 1.0))):
        assert _feed(stream) == (stream, [])


@pytest.mark.parametrize("alone", [True, False])
def test_cadence_a_real_gap_of_several_seconds_loses_nothing(alone):
    gps = _every("gps", 0.0, 10.0, 0.2) + _every("gps", 13.0, 20.0, 0.2)     # 3 s without a fix
    stream = gps if alone else _merge(_every("imu", 0.0, 20.0, 0.01), gps)
    assert _feed(stream) == (stream, [])
    # the whole stream paused 3 s (inside future_s), IMU and GPS alike
    paused = [(s, t + 3.0 if t > 10.0 else t) for s, t in _merge(_every("imu", 0.0, 20.0, 0.01), _every("gps", 0.0, 20.0, 0.2))]
    assert _feed(paused) == (paused, [])


@pytest.mark.parametrize("alone", [True, False])
def test_cadence_a_sensor_with_irregular_spacing_loses_nothing(alone):
    rng = random.Random(3)
    t, ev = 0.0, []
    for _ in range(400):            # event-driven: exponential spacing, mean 0.3 s, and 1-4 s silences
        t += rng.expovariate(1 / 0.3) if rng.random() > 0.05 else rng.uniform(1.0, 4.0)
        ev.append(("door", round(t, 6)))
    stream = ev if alone else _merge(_every("imu", 0.0, t + 0.5, 0.01), ev)
    fed, events = _feed(stream)
    assert fed == stream and events == []


@pytest.mark.parametrize("alone", [True, False])
def test_cadence_a_rate_change_10_to_50_hz_and_back_loses_nothing(alone):
    uwb = _every("uwb", 0.0, 10.0, 0.1) + _every("uwb", 10.0, 20.0, 0.02) + _every("uwb", 20.0, 30.0, 0.1)
    stream = uwb if alone else _merge(_every("imu", 0.0, 30.0, 0.01), uwb)
    assert _feed(stream) == (stream, [])


def test_cadence_holds_delay_no_other_sensor_and_never_move_the_horizon():
    real = _merge(_every("imu", 0.0, 4.0, 0.01), _every("gps", 0.5, 4.0, 1.0))
    wild = [(s, t + 2.0 if (s, t) == ("gps", 1.5) else t) for s, t in real]
    spec = SchedulerSpec()
    g = ClockGuard(spec.future_s, spec.resync_after, cadence_k=spec.cadence_k, cadence_floor_s=spec.cadence_floor_s,
                   sensors={"imu", "gps"})
    newest, k = -math.inf, wild.index(("gps", 3.5))
    for i, (s, t) in enumerate(wild):
        out, events = g.admit(s, Message(t, s, (1.0,)), t, newest)
        if i == k:
            assert g.held() == 1 and out == [] and g.busy
        elif s == "imu":                        # fed at once while the GPS stamp is held
            assert [(m.sensor, tc) for m, tc in out] == [(s, t)]
        elif t == 2.5:                          # the next GPS fix, before it: it was wild
            assert [e.kind for e in events] == ["time"] and g.held() == 0 and not g.busy
        newest = max([newest] + [tc for _, tc in out])
        assert newest < 3.5 or t >= 3.5          # the held stamp never moved the stream's time


def test_cadence_settings_are_validated():
    from pydantic import ValidationError

    assert SchedulerSpec().cadence_k == 2.0 and SchedulerSpec().cadence_floor_s == 0.02
    for bad in ({"cadence_k": -1}, {"cadence_floor_s": 0.0}, {"cadence_floor_s": 6.0}, {"cadence_k": float("nan")}):
        with pytest.raises(ValidationError):
            SchedulerSpec(**bad)
    off = _merge(_every("imu", 0.0, 5.0, 0.01), [("abps", 2.5)])     # cadence_k 0: off, as before
    assert _feed(off, cadence_k=0.0)[0] == off


def _abps(lines, sensor, k, fn):
    """``lines`` with the ``k``-th line of ``sensor`` re-stamped by ``fn``."""
    idx = [i for i, ln in enumerate(lines) if f",{sensor}," in ln][k]
    out = lines[:]
    t, rest = out[idx].split(",", 1)
    out[idx] = f"{fn(float(t))!r},{rest}"
    return out


@pytest.fixture(scope="module")
def abps_lines():
    return (ROOT / "recordings" / "abps_mine.log").read_text().splitlines()


@pytest.fixture(scope="module")
def abps_reference(abps_lines):
    return _run(abps_lines, ABPS)


@pytest.mark.parametrize("k, ahead", [(0, 1.0), (300, 1.0), (300, 0.4), (700, 3.0)])
def test_cadence_abps_a_range_stamped_ahead_loses_no_imu_sample(abps_lines, abps_reference, k, ahead):
    """Issue 10 item 9 (k 0: the fuzz case, the first range): IMU samples after it used to be late."""
    s = _run(_abps(abps_lines, "abps", k, lambda t: t + ahead), ABPS)
    ref = abps_reference["sensors"]
    assert s["sensors"]["imu"]["used"] == ref["imu"]["used"] and s["sensors"]["imu"]["late"] == 0
    assert s["sensors"]["abps"]["malformed"] == 1 and s["sensors"]["abps"]["late"] == ref["abps"]["late"]
    assert s["events"]["time"] == 1


def test_cadence_abps_real_gaps_lose_nothing(abps_lines, abps_reference):
    """The ranges silent 4 s while the IMU goes on; then the whole stream paused 3 s (inside future_s)."""
    silent = [ln for ln in abps_lines if not (",abps," in ln and 50.0 < float(ln.split(",", 1)[0]) < 54.0)]
    s = _run(silent, ABPS)
    assert s["sensors"]["imu"]["used"] == abps_reference["sensors"]["imu"]["used"]
    assert s["sensors"]["abps"]["late"] == 0 and s["sensors"]["abps"]["malformed"] == 0 and "time" not in s["events"]
    paused = _run(_retime(abps_lines, lambda t: t + 3.0 if t > 60.0 else t), ABPS)
    assert paused["sensors"]["imu"]["used"] == abps_reference["sensors"]["imu"]["used"]
    assert paused["sensors"]["abps"]["received"] == abps_reference["sensors"]["abps"]["received"]
    assert paused["sensors"]["abps"]["late"] == 0 and paused["sensors"]["abps"]["malformed"] == 0


def test_a_wild_first_stamp_does_not_become_the_time_base(tmp_path):
    """The very first line stamped 1.7e9 s (a Unix time, a bit flip): the messages after it agree on the
    recording's time, so it is the one dropped (counted malformed, a time event), and the run is the clean
    run's, estimate for estimate."""
    from pathlib import Path

    from fusion import pipeline
    from fusion.config import load_system

    root = Path(__file__).resolve().parents[2]
    lines = (root / "recordings" / "uwb_route1.log").read_text().splitlines()
    body = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    wild = lines[:body] + ["1700000000.0,uwb,B1,4.4"] + lines[body:]
    system = load_system(root / "configs" / "uwb_pv_ukf.yaml")
    clean, dirty = pipeline.Collect(), pipeline.Collect()
    ref = pipeline.run(system, [ln + "\n" for ln in lines], [clean])
    events = []
    got = pipeline.run(system, [ln + "\n" for ln in wild], [dirty], on_event=events.append)
    assert got.summary["sensors"]["uwb"]["malformed"] == 1
    assert got.summary["sensors"]["uwb"]["used"] == ref.summary["sensors"]["uwb"]["used"]
    assert [e.t for e in dirty.estimates] == [e.t for e in clean.estimates]
    assert any(e.kind == "time" and "1700000000.0" in e.detail for e in events)
    assert not any(e.kind == "clock" for e in events)


def test_fewer_messages_than_the_start_waits_for_still_run():
    """Two messages in all (the start waits for three that agree): both are fed at the end of input."""
    from fusion.api import Message

    guard = ClockGuard(future_s=5.0, agree=3, hold_start=True)
    assert guard.admit("a", Message(0.0, "a", (1.0,)), 0.0, -math.inf) == ([], [])
    assert guard.admit("b", Message(0.1, "b", (1.0,)), 0.1, -math.inf) == ([], [])
    assert guard.held() == 2
    out = guard.release()
    assert [t for _, t in out] == [0.0, 0.1] and guard.held() == 0 and not guard.busy


def test_a_lone_sensor_slower_than_future_s_is_not_dropped_as_wild():
    """A fix every 8 s, alone in the stream (future_s 5 s): each stamp is past the bound, and the next was
    8 s on, so 'the messages after it do not agree' dropped every one but the first (tester4 #15). Alone,
    messages stepping forward agree; a wild stamp among them (going back) is still dropped."""
    slow = [("uwb", 8.0 * k) for k in range(12)]
    fed, events = _feed(slow, inputs=())
    assert fed[:10] == slow[:10]                      # in order and kept (the last ones wait for agreement)
    assert not any(e.kind == "time" for e in events)
    wild = slow[:5] + [("uwb", 1e9)] + slow[5:]
    fed, events = _feed(wild, inputs=())
    assert ("uwb", 1e9) not in fed and fed[:5] == slow[:5]
    fed_with_imu, _ = _feed(_merge(slow, _every("imu", 0.0, 90.0, 0.01)))   # another stream on the base:
    assert [p for p in fed_with_imu if p[0] == "uwb"] == slow                # its messages are on the time
