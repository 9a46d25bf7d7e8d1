"""Nothing cut at the sizes the docs show (issue 28 item 3): at 80 x 24 the key bar keeps every key it
shows and the status line stays one line; at 120 x 40 the abps state (17 elements) fits the left column and
the health panel is whole, border included. The pictures are in test_tui_snapshots.py; these say what in
them must hold."""
import asyncio
from pathlib import Path

import pytest

from fusion.tui.app import make_app
from fusion.tui.health_panel import HealthPanel
from fusion.tui.state_table import StateTable
from fusion.tui.status_line import StatusLine

ROOT = Path(__file__).resolve().parents[2]


def screen_lines(app) -> list[str]:
    return ["".join(seg.text for seg in strip) for strip in app.screen._compositor.render_strips()]


def held(config: str, size: tuple[int, int], t: float, check, keys: tuple[str, ...] = ()):
    async def drive():
        app = make_app(ROOT / "configs" / config, speed=0, pause_at=t)
        async with app.run_test(size=size) as pilot:
            while not (app.feed.paused and app.latest is not None and app.latest.sensor_t >= t and app.paused):
                await pilot.pause(0.02)
            for key in keys:
                await pilot.press(key)
            await pilot.pause(0.6)   # past the layout's half-second tick
            check(app)
    asyncio.run(drive())


@pytest.mark.parametrize("tab", ["1", "2", "4"])
def test_80x24_keeps_its_key_bar_and_a_one_line_status(tab):
    def check(app):
        lines = screen_lines(app)
        assert len(lines) == 24
        keys = lines[-1]
        for shown in ("q quit", "p pause", "n step", "r reset", "s sensor", "? help", "^p palette"):
            assert shown in keys, keys          # not "s plo▏^p palette", the help key cut off
        status = app.query_one(StatusLine)
        assert status.size.height == 1, status.text   # not two lines ("8424 lines" wrapped)
        assert "PAUSED" in status.text and "OK" in status.text and "t = 40.000 s" in status.text
        assert lines[-2].startswith(status.text.rstrip()[:40])
    held("abps_ins.yaml", (80, 24), 40.0, check, (tab,))


def test_120x40_abps_state_and_health_fit_the_left_column():
    def check(app):
        left = app.query_one("#left")
        health = app.query_one(HealthPanel)
        assert health.region.bottom <= left.region.bottom   # its bottom border not hidden below the column
        assert left.region.bottom <= app.query_one("EventLog").region.y
        box = app.query_one("#state-scroll")
        table = app.query_one(StateTable)
        # 17 state elements, the quaternion shown as roll, pitch, yaw: 16 rows, every one shown, none scrolled away
        assert len(table.cells) == 16 and box.max_scroll_y == 0
        text = "\n".join(screen_lines(app))
        assert "│ hz " in text and "╰" in screen_lines(app)[health.region.bottom - 1]
    held("abps_ins.yaml", (120, 40), 40.0, check)


def test_a_state_longer_than_the_column_scrolls_inside_it_and_the_health_stays_whole():
    def check(app):
        left, health, box = app.query_one("#left"), app.query_one(HealthPanel), app.query_one("#state-scroll")
        assert health.region.bottom <= left.region.bottom
        assert box.max_scroll_y > 0      # at the smallest wide size the 17 elements scroll (a scrollbar shows)
    held("abps_ins.yaml", (120, 36), 40.0, check)
