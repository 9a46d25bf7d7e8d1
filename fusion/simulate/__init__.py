"""``fusion simulate``: scenarios -> physically consistent recordings with truth (docs/simulate.md).

The names below load on first use: simulator plugins import ``fusion.simulate.base`` at start-up of
every command, and the engine pulls in scipy.interpolate (~0.3 s), which only ``fusion simulate`` needs.
"""
from __future__ import annotations

import importlib
from typing import Any

__all__ = ["Scenario", "load_scenario", "parse_scenario", "simulate", "simulate_file"]

_WHERE = {"simulate": "engine", "simulate_file": "engine", "Scenario": "scenario", "load_scenario": "scenario",
          "parse_scenario": "scenario"}


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(f"fusion.simulate.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'fusion.simulate' has no attribute {name!r}")
