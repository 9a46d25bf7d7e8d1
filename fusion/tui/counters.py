"""Per-sensor counters: received, used, rejected, malformed, late, and the rate by sensor time."""
from __future__ import annotations

from textual.widgets import Static

from fusion.tui.feed import COUNTERS
from fusion.tui.text_table import text_table


class SensorCounters(Static):
    """One row a sensor; messages of sensors not in the config show as ignored. ``values`` holds the
    counters shown, ``cells`` the texts of each row by sensor (``ignored:NAME`` for ignored ones)."""

    DEFAULT_CSS = """
    SensorCounters { height: auto; max-height: 14; padding: 0 1; }
    """

    def __init__(self, **kwargs) -> None:
        super().__init__("no messages yet", **kwargs)
        self.border_title = "sensors"
        self.values: dict[str, dict[str, int]] = {}
        self.cells: dict[str, tuple[str, ...]] = {}

    def show(self, counters: dict[str, dict[str, int]], ignored: dict[str, int], rates: dict[str, float]) -> None:
        self.values = {k: dict(v) for k, v in counters.items()}
        cells: dict[str, tuple[str, ...]] = {}
        styles = []
        for name, row in counters.items():
            rate = rates.get(name)
            cells[name] = (name, *(str(row.get(c, 0)) for c in COUNTERS), f"{rate:.1f}" if rate is not None else "")
            bad = row.get("rejected", 0) + row.get("malformed", 0) + row.get("late", 0)
            styles.append("yellow" if bad else None)
        for name, n in ignored.items():
            cells[f"ignored:{name}"] = (f"{name} (not in config)", str(n), "0", "", "", "", "")
            styles.append("dim")
        self.cells = cells
        self.update(text_table(("sensor", *COUNTERS, "Hz"), list(cells.values()),
                               right=(False, *([True] * (len(COUNTERS) + 1))), styles=styles))
