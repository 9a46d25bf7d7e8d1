"""Pictures of the main screen (pytest-textual-snapshot) at 120x40 and 80x24, each at a fixed replay time
(``make_app(..., pause_at=T)`` holds the replay at sensor time T, so the picture does not depend on the
machine's speed). Regenerate after an intended change of the look, and look at the pictures:
``pytest tests/tui/test_tui_snapshots.py --snapshot-update`` (files in __snapshots__/)."""
from pathlib import Path

import pytest

from fusion.tui.app import make_app

ROOT = Path(__file__).resolve().parents[2]
CASES = {
    "example_2d_120x40_t30": ("example_2d.yaml", (120, 40), 30.0, ()),
    "abps_ins_120x40_t40": ("abps_ins.yaml", (120, 40), 40.0, ()),
    "abps_ins_80x24_t40_state": ("abps_ins.yaml", (80, 24), 40.0, ()),
    "abps_ins_80x24_t40_sensors": ("abps_ins.yaml", (80, 24), 40.0, ("2",)),
    "abps_ins_80x24_t40_innovations": ("abps_ins.yaml", (80, 24), 40.0, ("4",)),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_main_screen(case, snap_compare):
    config, size, t, keys = CASES[case]
    app = make_app(ROOT / "configs" / config, speed=0, pause_at=t)

    async def held(pilot):
        while not (app.feed.paused and app.latest is not None and app.latest.sensor_t >= t and app.paused):
            await pilot.pause(0.02)
        await pilot.pause(0.2)

    assert snap_compare(app, press=keys, terminal_size=size, run_before=held)
