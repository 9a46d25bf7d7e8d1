"""The state table: each state element by name with its value, 1-sigma and unit."""
from __future__ import annotations

from textual.widgets import DataTable

from fusion.api import Estimate, StateLayout
from fusion.tui.state_rows import fmt_sd, fmt_value, state_rows


class StateTable(DataTable):
    """Latest estimate, one row a state element (attitude as roll/pitch/yaw, deg). Row keys are the
    element names (``px``, ``roll``), columns ``value``, ``sd``, ``unit``."""

    DEFAULT_CSS = """
    StateTable { height: auto; max-height: 24; }
    """

    def __init__(self, layout: StateLayout, **kwargs) -> None:
        super().__init__(cursor_type="none", zebra_stripes=True, **kwargs)
        self.state_layout = layout
        self._keys: list[str] = []
        self.border_title = "state"

    def on_mount(self) -> None:
        self.add_column("element", key="element")
        self.add_column("value", key="value", width=14)
        self.add_column("1σ", key="sd", width=10)
        self.add_column("unit", key="unit")

    def show(self, estimate: Estimate | None) -> None:
        """Show an estimate (None: nothing yet)."""
        if estimate is None:
            return
        rows = state_rows(self.state_layout, estimate.belief)
        keys = [r.key for r in rows]
        if keys != self._keys:
            self.clear()
            for r in rows:
                self.add_row(r.key, fmt_value(r.value), fmt_sd(r.sd), r.unit, key=r.key)
            self._keys = keys
        else:
            for r in rows:
                self.update_cell(r.key, "value", fmt_value(r.value))
                self.update_cell(r.key, "sd", fmt_sd(r.sd))
        why = f"update {estimate.sensor}" if estimate.reason == "update" and estimate.sensor else estimate.reason
        self.border_title = f"state at t = {estimate.t:.3f} s ({why})"
