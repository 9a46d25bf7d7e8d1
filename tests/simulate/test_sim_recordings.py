"""The shipped recordings are what their scenarios produce (python scripts/make_recordings.py).

Compared as numbers, not bytes: a recording writes each value rounded to a fixed number of decimals, and a
value within a rounding boundary of a printed digit (or of zero, where `-0.000000` and `0.000000` are the
same number) can round either way when numpy's or libm's last bit differs between releases. So every line
must have the same sensor and field count, every label the same text, and every number the same value to
one unit of its last written decimal; the metadata (`#` lines) must match exactly.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from fusion.simulate import simulate_file

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = sorted((ROOT / "scenarios").glob("*.yaml"))


def _last_digit_unit(token: str) -> float:
    """One unit of the last decimal written in ``token`` (1 for an integer)."""
    mantissa = token.lower().split("e")[0]
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    exponent = int(token.lower().split("e")[1]) if "e" in token.lower() else 0
    return 10.0 ** (exponent - decimals)


def _as_number(token: str) -> float | None:
    try:
        return float(token)
    except ValueError:
        return None


def _line_difference(shipped: str, regenerated: str) -> str | None:
    """Why two recording lines differ beyond the last written digit, or None when they agree."""
    if shipped.startswith("#") or regenerated.startswith("#"):
        return None if shipped == regenerated else "metadata differs"
    a, b = shipped.split(","), regenerated.split(",")
    if len(a) != len(b):
        return f"{len(a)} fields against {len(b)}"
    for k, (x, y) in enumerate(zip(a, b)):
        nx, ny = _as_number(x), _as_number(y)
        if nx is None or ny is None:
            if x != y:
                return f"field {k}: {x!r} against {y!r}"
        elif abs(nx - ny) > 1.000001 * max(_last_digit_unit(x), _last_digit_unit(y)):
            return f"field {k}: {x} against {y}"
    return None


@pytest.mark.parametrize("scenario", SCENARIOS, ids=[s.stem for s in SCENARIOS])
def test_recording_matches_its_regeneration(scenario):
    rec = ROOT / "recordings" / f"{scenario.stem}.log"
    assert rec.exists(), f"{rec} missing: run python scripts/make_recordings.py"
    shipped = rec.read_text(encoding="utf-8").splitlines()
    regenerated = simulate_file(str(scenario)).splitlines()
    assert len(shipped) == len(regenerated), \
        f"{rec}: {len(shipped)} lines, regenerated {len(regenerated)}: run python scripts/make_recordings.py"
    for lineno, (a, b) in enumerate(zip(shipped, regenerated), start=1):
        why = _line_difference(a, b)
        assert why is None, f"{rec}:{lineno}: {why}: run python scripts/make_recordings.py {scenario.stem}"


def test_comparison_tolerates_only_the_last_digit():
    assert _line_difference("1.000000,imu,-0.000000,2.5", "1.000000,imu,0.000000,2.5") is None
    assert _line_difference("1.000000,imu,0.123457", "1.000000,imu,0.123456") is None
    assert _line_difference("1.000000,imu,0.123458", "1.000000,imu,0.123456") is not None
    assert _line_difference("1.000000,imu,0.1", "1.000000,gps,0.1") is not None
    assert _line_difference("1.0,imu,0.1", "1.0,imu,0.1,0.2") is not None
    assert _line_difference("# origin: 1 2", "# origin: 1 3") is not None


def test_recordings_are_small():
    total = sum(p.stat().st_size for p in (ROOT / "recordings").glob("*.log"))
    assert total < 20e6
