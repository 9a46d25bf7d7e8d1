"""Helpers of the tests of a config against its recording's world: temp scenarios and configs made from the
shipped ones with a few values changed."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml

from fusion.cli import main

ROOT = Path(__file__).resolve().parents[2]


def edited(src: Path, dest: Path, **changes: Any) -> Path:
    """``src`` (YAML) with top-level keys replaced (a dotted key sets a nested one), written to ``dest``."""
    data = yaml.safe_load(src.read_text())
    for key, value in changes.items():
        *path, last = key.split(".")
        node = data
        for k in path:
            node = node[k]
        if value is None:
            node.pop(last, None)
        else:
            node[last] = value
    dest.write_text(yaml.safe_dump(data, sort_keys=False))
    return dest


def simulate(scenario: Path, out: Path, seed: int | None = None) -> Path:
    args = ["simulate", str(scenario), "-o", str(out), "--force"]
    assert main(args + (["--seed", str(seed)] if seed is not None else [])) == 0
    return out


def run(config: Path, recording: Path | None, out: Path, *extra: str) -> tuple[int, dict | None]:
    args = ["run", str(config), "-q", "--no-progress", "--summary-json", str(out), "--force", *extra]
    code = main(args + (["--input", str(recording)] if recording is not None else []))
    return code, json.loads(out.read_text()) if out.exists() else None


@pytest.fixture
def root() -> Path:
    return ROOT
