"""The live view's newer parts: the UDP JSON stream on loopback, single step, tabs in small terminals,
the help screen, the innovation plots' choice of sensor and the track's ellipse, follow and zoom."""
import asyncio
import json
import math
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from fusion import pipeline
from fusion.api import ConfigError
from fusion.config import load_system
from fusion.tui.app import FusionApp, make_app
from fusion.tui.help_screen import HelpScreen
from fusion.tui.innovation_plot import InnovationPanel
from fusion.tui.state_table import StateTable
from fusion.tui.track_plot import TrackPlot, ellipse_points
from fusion.tui.udp import parse_address

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"
ABPS = ROOT / "configs" / "abps_ins.yaml"
RECORDING = ROOT / "recordings" / "example_2d.log"
DONE = ("finished", "lost", "error", "stopped")


async def until(pilot, cond, what, timeout=20.0):
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        await pilot.pause(0.02)


def reference(path):
    kept = pipeline.Collect()
    pipeline.run(load_system(CONFIG), path, [kept])
    return kept.estimates


def test_udp_stream_sends_every_estimate_as_plotjuggler_json(tmp_path):
    log = tmp_path / "part.log"
    log.write_text("".join(RECORDING.read_text().splitlines(True)[:700]))
    ref = reference(log)
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(0.2)
    got, done = [], threading.Event()

    def receive():  # until the view has ended and nothing more is waiting
        while True:
            try:
                got.append(json.loads(rx.recv(65536)))
            except socket.timeout:
                if done.is_set():
                    return

    reader = threading.Thread(target=receive)
    reader.start()

    async def drive():
        app = make_app(CONFIG, log, speed=0, udp=f"127.0.0.1:{rx.getsockname()[1]}")
        async with app.run_test(size=(120, 40)) as pilot:
            await until(pilot, lambda: app.latest is not None and app.latest.state in DONE, "the end")
            await pilot.press("q")

    try:
        asyncio.run(drive())
    finally:
        done.set()
    reader.join()
    rx.close()
    assert len(got) == len(ref)
    gate = chi2.ppf(0.9999, 1)  # the config's gate: probability 0.9999, 1-D ranges
    for msg, est in zip(got, ref):
        assert msg["timestamp"] == est.t
        assert [msg["state"][k] for k in ("px", "py", "vx", "vy")] == est.belief.x.tolist()
        assert msg["sd"]["px"] == pytest.approx(math.sqrt(est.belief.P[0, 0]), rel=1e-12)
        inn = msg["innovation"]["uwb"]
        assert inn["y0"] == pytest.approx(float(est.update.innovation[0]), rel=1e-12)
        assert inn["sqrt_S0"] == pytest.approx(math.sqrt(est.update.S[0, 0]), rel=1e-12)
        assert inn["ratio"] == pytest.approx(est.update.nis / gate, rel=1e-9)
        assert inn["accepted"] == 1 and inn["dim"] == 1


@pytest.mark.parametrize("text, words", [("localhost", "expected HOST:PORT"), ("h:0", "1 to 65535"),
                                         ("h:x", "1 to 65535")])
def test_bad_udp_address_is_one_config_error(text, words):
    with pytest.raises(ConfigError, match=words):
        parse_address(text)
    assert parse_address("[::1]:9870") == ("::1", 9870) and parse_address(":9870") == ("127.0.0.1", 9870)


def test_single_step_advances_a_paused_replay_one_estimate_at_a_time():
    times = [e.t for e in reference(RECORDING)]

    async def drive():
        app = make_app(CONFIG, speed=0, pause_at=10.0)
        async with app.run_test(size=(120, 40)) as pilot:
            await until(pilot, lambda: app.feed.paused and app.latest is not None and app.latest.sensor_t >= 10.0,
                        "the pause at 10 s")
            await pilot.pause(0.1)
            assert app.paused
            start = app.latest.estimate.t
            i = times.index(start)
            for k in range(1, 4):
                await pilot.press("n")
                await until(pilot, lambda: app.latest.estimate.t != times[i + k - 1], f"step {k}")
                await pilot.pause(0.1)
                assert app.latest.estimate.t == times[i + k]  # exactly the next estimate, then held
                assert app.query_one(StateTable).border_title.startswith(f"state at t = {times[i + k]:.3f} s")
            await pilot.press("q")

    asyncio.run(drive())


def test_small_terminal_gets_tabs_and_nothing_is_cut():
    async def drive():
        app = make_app(ABPS, speed=0, pause_at=20.0)
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.feed.paused and app.latest is not None and app.latest.sensor_t >= 20.0,
                        "the pause")
            await pilot.pause(0.2)
            assert app.wide is False
            table = app.query_one(StateTable)
            n_rows = len(table.cells)
            assert n_rows == 16  # p v (3 + 3), roll pitch yaw, ba bw (3 + 3), hz (the fix height error)
            assert table.outer_size.height == n_rows + 3  # header and borders: every row laid out
            for key, tab in (("2", "tab-sensors"), ("3", "tab-track"), ("4", "tab-plots"), ("5", "tab-events"),
                             ("6", "tab-states")):
                await pilot.press(key)
                await pilot.pause(0.05)
                assert app.query_one("#tabs").active == tab
            await pilot.resize_terminal(130, 40)
            await until(pilot, lambda: app.wide is True, "the wide layout")
            await pilot.pause(0.2)
            assert not app.query("#tabs") and app.query_one(StateTable).cells
            await pilot.press("q")

    asyncio.run(drive())


HELP_NAMES = {"plus": "+", "equals_sign": "+", "minus": "-", "question_mark": "?"}


def test_help_screen_lists_every_key():
    async def drive():
        app = make_app(CONFIG, speed=0, pause_at=5.0)
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("question_mark")
            await pilot.pause(0.1)
            screen = app.screen
            assert isinstance(screen, HelpScreen)
            listed = " ".join(k for k, _ in screen.keys)
            for binding in FusionApp.BINDINGS:
                key = binding.key.split(",")[0]
                name = HELP_NAMES.get(key, key)
                assert name in listed or (name.isdigit() and "1-6" in listed), key
            await pilot.press("escape")
            await pilot.pause(0.05)
            assert not isinstance(app.screen, HelpScreen)
            await pilot.press("q")

    asyncio.run(drive())


def test_innovation_panel_sensor_key_and_track_keys():
    async def drive():
        app = make_app(ABPS, speed=0, pause_at=30.0)
        async with app.run_test(size=(130, 44)) as pilot:
            await until(pilot, lambda: app.feed.paused and app.latest is not None and app.latest.sensor_t >= 30.0,
                        "the pause")
            await pilot.pause(0.2)
            panel = app.query_one(InnovationPanel)
            assert panel.sensor == "abps" and set(app.latest.series) == {"abps"}
            samples = app.latest.series["abps"]
            assert samples and all(len(s.y) == len(s.sd) for s in samples)
            await pilot.press("e")
            assert panel.element == 1 % len(samples[-1].y)
            track = app.query_one(TrackPlot)
            assert track.cov is not None and track.cov.shape == (2, 2)
            await pilot.press("plus", "plus", "f")
            assert track.zoom == 4.0 and track.follow
            assert "follow zoom 4x" in track.render().plain
            await pilot.press("0")
            assert track.zoom == 1.0 and not track.follow
            await pilot.press("q")

    asyncio.run(drive())


def test_ellipse_points_are_the_2_sigma_contour():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(2, 2))
    P = A @ A.T + 0.1 * np.eye(2)
    pts = ellipse_points(np.array([1.0, -2.0]), P, k=2.0, n=200)
    d = pts - np.array([1.0, -2.0])
    m2 = np.einsum("ij,jk,ik->i", d, np.linalg.inv(P), d)  # Mahalanobis distance squared
    np.testing.assert_allclose(m2, 4.0, rtol=1e-9)


@pytest.mark.parametrize("config", sorted(p.name for p in (ROOT / "configs").glob("*.yaml") if p.name != "example_2d.yaml"))
def test_every_shipped_config_replays_in_the_view_to_the_end(config):
    """(example_2d.yaml is replayed to the end in test_tui_app.py.) The view ends where fusion run ends."""
    system = load_system(ROOT / "configs" / config)
    last = pipeline.run(system, system.recording).last

    async def drive():
        app = make_app(ROOT / "configs" / config, speed=0)
        async with app.run_test(size=(120, 40)) as pilot:
            await until(pilot, lambda: app.latest is not None and app.latest.state in DONE, "the end", timeout=60)
            await pilot.pause(0.05)
            assert app.latest.state == "finished", app.latest.message
            np.testing.assert_array_equal(app.latest.estimate.belief.x, last.belief.x)
            assert app.latest.health.state == "OK"
            await pilot.press("q")

    asyncio.run(drive())


def test_state_errors_against_truth_match_an_interpolation_of_the_recording():
    rows = [ln.split(",") for ln in RECORDING.read_text().splitlines() if ",truth," in ln]
    header = next(ln for ln in RECORDING.read_text().splitlines() if ln.startswith("# fields truth"))
    names = header.split()[3:]
    tt = np.array([float(r[0]) for r in rows])
    true_px = np.array([float(r[2 + names.index("px")]) for r in rows])

    async def drive():
        app = make_app(CONFIG, speed=0, pause_at=40.0)
        async with app.run_test(size=(120, 40)) as pilot:
            await until(pilot, lambda: app.feed.paused and app.latest is not None and app.latest.sensor_t >= 40.0,
                        "the pause")
            await pilot.pause(0.1)
            samples = app.latest.states
            k = app.feed.states.names.index("px")
            t = np.array([s.t for s in samples])
            err = np.array([s.err[k] for s in samples])
            x = np.array([s.x[k] for s in samples])
            sd = np.array([s.sd[k] for s in samples])
            ok = np.isfinite(err)
            assert ok.sum() > 300 and np.all(np.diff(t) >= 0.1 - 1e-9)
            np.testing.assert_allclose(err[ok], x[ok] - np.interp(t[ok], tt, true_px), rtol=0, atol=1e-9)
            settled = ok & (t > 10.0)
            assert np.mean(np.abs(err[settled]) <= 3 * sd[settled]) > 0.95  # consistent: inside +-3 sigma
            await pilot.press("v")
            assert app.query_one("#plot-switch").current == "states"
            await pilot.press("x")
            assert app.query_one("#states").element == 1
            await pilot.press("q")

    asyncio.run(drive())
