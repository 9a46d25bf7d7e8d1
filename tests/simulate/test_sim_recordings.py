"""The shipped recordings are exactly what their scenarios produce (python scripts/make_recordings.py)."""
from __future__ import annotations

from pathlib import Path

import pytest

from fusion.simulate import simulate_file

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = sorted((ROOT / "scenarios").glob("*.yaml"))


@pytest.mark.parametrize("scenario", SCENARIOS, ids=[s.stem for s in SCENARIOS])
def test_recording_is_byte_identical_to_regeneration(scenario):
    rec = ROOT / "recordings" / f"{scenario.stem}.log"
    assert rec.exists(), f"{rec} missing: run python scripts/make_recordings.py"
    assert simulate_file(str(scenario)).encode("utf-8") == rec.read_bytes(), \
        f"{rec} differs from its scenario: run python scripts/make_recordings.py {scenario.stem}"


def test_recordings_are_small():
    total = sum(p.stat().st_size for p in (ROOT / "recordings").glob("*.log"))
    assert total < 20e6
