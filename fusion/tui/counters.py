"""Per-sensor counters: received, used, rejected, malformed, late, and the rate by sensor time."""
from __future__ import annotations

from textual.widgets import DataTable

from fusion.tui.feed import COUNTERS


class SensorCounters(DataTable):
    """One row a sensor (row key: its name); messages of sensors not in the config show as ignored."""

    DEFAULT_CSS = """
    SensorCounters { height: auto; max-height: 12; }
    """

    def __init__(self, **kwargs) -> None:
        super().__init__(cursor_type="none", zebra_stripes=True, **kwargs)
        self.border_title = "sensors"
        self.values: dict[str, dict[str, int]] = {}

    def on_mount(self) -> None:
        self.add_column("sensor", key="sensor")
        for name in COUNTERS:
            self.add_column(name, key=name, width=max(len(name), 8))
        self.add_column("Hz", key="rate", width=7)

    def show(self, counters: dict[str, dict[str, int]], ignored: dict[str, int], rates: dict[str, float]) -> None:
        self.values = {k: dict(v) for k, v in counters.items()}
        for name, row in counters.items():
            rate = rates.get(name)
            cells = [str(row.get(c, 0)) for c in COUNTERS] + [f"{rate:.1f}" if rate is not None else ""]
            self._put(name, name, cells)
        for name, n in ignored.items():
            self._put(f"ignored:{name}", f"{name} (not in config)", [str(n), "0", "", "", "", ""])

    def _put(self, key: str, label: str, cells: list[str]) -> None:
        if key not in self.rows:
            self.add_row(label, *cells, key=key)
            return
        for col, value in zip((*COUNTERS, "rate"), cells):
            self.update_cell(key, col, value)
