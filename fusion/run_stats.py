"""What a run counts: re-exported from fusion.run.stats (its home)."""
from fusion.run.stats import ABSORBED, COUNTERS, RunStats  # noqa: F401

__all__ = ["RunStats", "COUNTERS", "ABSORBED"]
