"""``fusion simulate``: scenarios -> physically consistent recordings with truth (docs/simulate.md)."""
from fusion.simulate.engine import simulate, simulate_file
from fusion.simulate.scenario import Scenario, load_scenario, parse_scenario

__all__ = ["Scenario", "load_scenario", "parse_scenario", "simulate", "simulate_file"]
