"""Small sweeps of the shipped UWB system (configs/uwb_pv_ukf.yaml, scenarios/uwb_route1.yaml cut to a
few seconds so a trial takes a fraction of a second)."""
from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CONFIG = str(ROOT / "configs" / "uwb_pv_ukf.yaml")
SCENARIO = str(ROOT / "scenarios" / "uwb_route1.yaml")
SHORT = ("scenario.duration", "12.0")      # s of route 1: its first corner


@pytest.fixture
def trials():
    from fusion.sweep.grid import trials_of

    def make(seeds=range(3), filters=("ukf", "ekf"), params=(), smooth=False, initial="config"):
        return trials_of(CONFIG, SCENARIO, seeds, list(filters), [(SHORT[0], [SHORT[1]]), *params], smooth, initial)
    return make
