"""Shared fixtures of the output tests."""
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def short_example(tmp_path):
    """(config, recording) in tmp_path: configs/example_2d.yaml on its own copy of the first 400 lines of
    recordings/example_2d.log (a run of ~0.1 s whose input lives next to its outputs)."""
    rec = tmp_path / "walk.log"
    rec.write_text("".join((ROOT / "recordings" / "example_2d.log").read_text().splitlines(True)[:400]))
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text((ROOT / "configs" / "example_2d.yaml").read_text().replace("../recordings/example_2d.log", "walk.log"))
    return cfg, rec
