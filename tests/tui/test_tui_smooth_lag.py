"""``fusion tui --smooth-lag SECONDS``: the fixed-lag smoothed estimate as a second trace in the track and
the state plot, driven headless (App.run_test + pilot), checked against ``fusion run --smooth-lag``."""
import time
from pathlib import Path

import numpy as np
import pytest

from fusion import pipeline
from fusion.cli import build_parser, main
from fusion.commands.tui import build_app
from fusion.config import load_system
from fusion.smoothing import run_smoothed
from fusion.tui.app import make_app
from fusion.tui.state_plot import StatePlot
from fusion.tui.track_plot import TrackPlot

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"
SIZE = (130, 40)
DONE = ("finished", "lost", "error", "stopped")
LAG = 2.0


async def until(pilot, cond, what, guard_s=600.0):
    """Wait for ``cond``; the guard only keeps a broken app from hanging the suite (not a speed test)."""
    deadline = time.monotonic() + guard_s
    while not cond():
        assert time.monotonic() < deadline, f"never reached: {what}"
        await pilot.pause(0.02)


def decimated(estimates, dt=0.1):
    """(north, east) of the estimates kept by the view's rule: one per ``dt`` s of sensor time."""
    out, last = [], -np.inf
    for e in estimates:
        if e.t - last >= dt:
            out.append(e.belief.x[:2])
            last = e.t
    return np.array(out)


def offline(lag):
    system = load_system(CONFIG)
    kept = pipeline.Collect()
    run_smoothed(system, system.recording, [kept], lag=lag)
    filtered = pipeline.Collect()
    pipeline.run(load_system(CONFIG), system.recording, [filtered])
    return kept.estimates, filtered.estimates


def test_the_second_trace_is_the_fixed_lag_smoother_of_fusion_run():
    smoothed, filtered = offline(LAG)

    async def drive():
        app = make_app(CONFIG, speed=0, smooth_lag=LAG)
        async with app.run_test(size=SIZE) as pilot:
            await until(pilot, lambda: app.latest is not None and app.latest.state in DONE, "the end of the replay")
            await pilot.pause(0.05)
            snap = app.latest
            assert snap.state == "finished" and snap.smooth_lag == LAG
            # the live trace is still the filter's own (the recorder does not change it)
            np.testing.assert_array_equal(snap.estimate.belief.x, filtered[-1].belief.x)
            np.testing.assert_allclose(np.array(snap.track), decimated(filtered)[-len(snap.track):], atol=1e-12)
            # the second trace: the fixed-lag smoothed estimates of `fusion run --smooth-lag`, not the filtered ones
            want = decimated(smoothed)
            got = np.array(snap.smoothed)
            assert snap.smoothed_total == len(want)
            np.testing.assert_allclose(got, want[-len(got):], atol=1e-9)
            assert np.abs(got - decimated(filtered)[-len(got):]).max() > 1e-3
            track = app.query_one(TrackPlot)
            np.testing.assert_array_equal(track.smoothed, got)
            assert "smoothed 2 s late" in str(track.border_subtitle)
            plot = app.query_one(StatePlot)
            assert plot.smoothed and plot.smoothed == snap.smoothed_states
            # its errors against truth are smaller than the live ones (example_2d has truth)
            f_err = np.array([s.err[:2] for s in snap.states if s.err[0] == s.err[0]])
            s_err = np.array([s.err[:2] for s in snap.smoothed_states if s.err[0] == s.err[0]])
            assert len(s_err) > 50
            assert np.sqrt(np.mean(s_err ** 2)) < np.sqrt(np.mean(f_err ** 2))
            await pilot.press("r")  # reset view forgets the smoothed trail too
            assert len(track.smoothed) == 0

    import asyncio
    asyncio.run(drive())


def test_while_running_the_smoothed_trace_is_lag_seconds_behind():
    async def drive():
        app = make_app(CONFIG, speed=0, smooth_lag=LAG, pause_at=30.0)
        async with app.run_test(size=SIZE) as pilot:
            await until(pilot, lambda: app.feed.paused and app.latest is not None and app.latest.sensor_t >= 30.0,
                        "the replay holding at t = 30 s")
            await pilot.pause(0.1)
            snap = app.latest
            assert snap.smoothed_states, "no smoothed samples yet"
            newest = snap.smoothed_states[-1].t
            assert newest <= snap.estimate.t - LAG + 1e-9
            assert newest > snap.estimate.t - LAG - 1.0  # and it keeps up (within one output interval + decimation)
            app.feed.stop()

    import asyncio
    asyncio.run(drive())


def test_without_the_option_there_is_no_second_trace():
    async def drive():
        app = make_app(CONFIG, speed=0)
        async with app.run_test(size=SIZE) as pilot:
            await until(pilot, lambda: app.latest is not None and app.latest.state in DONE, "the end of the replay")
            snap = app.latest
            assert snap.smooth_lag is None and snap.smoothed == () and snap.smoothed_states == ()
            assert "smoothed" not in str(app.query_one(TrackPlot).border_subtitle)

    import asyncio
    asyncio.run(drive())


def test_the_option_reaches_the_app():
    args = build_parser().parse_args(["tui", str(CONFIG), "--speed", "0", "--smooth-lag", "1.5"])
    app = build_app(args)
    assert app.feed.smooth_lag == 1.5


@pytest.mark.parametrize("value", ["-1", "nan", "inf"])
def test_a_bad_lag_exits_2_with_one_line(value, capsys):
    assert main(["tui", str(CONFIG), f"--smooth-lag={value}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--smooth-lag" in err[0]


@pytest.mark.parametrize("config, t", [("example_2d.yaml", 30.0), ("abps_ins.yaml", 40.0)])
def test_picture_with_the_smoothed_trace(config, t, snap_compare):
    """The main screen at 120x40 with ``--smooth-lag 2``, held at sensor time t (the state plot shown,
    key v, so both traces are in the picture). Regenerate: ``pytest tests/tui/test_tui_smooth_lag.py
    --snapshot-update``."""
    app = make_app(ROOT / "configs" / config, speed=0, pause_at=t, smooth_lag=LAG)

    async def held(pilot):
        while not (app.feed.paused and app.latest is not None and app.latest.sensor_t >= t and app.paused):
            await pilot.pause(0.02)
        await pilot.pause(0.2)

    assert snap_compare(app, press=("v",), terminal_size=(120, 40), run_before=held)
