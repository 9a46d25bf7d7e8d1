"""Fixtures of the tests of a config against its recording's world (the helpers: world_helpers.py)."""
from __future__ import annotations

from pathlib import Path

import pytest

from world_helpers import ROOT


@pytest.fixture
def root() -> Path:
    return ROOT
