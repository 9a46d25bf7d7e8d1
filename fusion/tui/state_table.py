"""The state table: each state element by name with its value, 1-sigma and unit."""
from __future__ import annotations

from textual.widgets import Static

from fusion.api import Estimate, StateLayout
from fusion.tui.state_rows import fmt_sd, fmt_value, state_rows
from fusion.tui.text_table import text_table


class StateTable(Static):
    """Latest estimate, one row a state element (attitude as roll/pitch/yaw, deg). ``cells`` maps each
    element name (``px``, ``roll``) to the texts shown: value, 1-sigma, unit."""

    DEFAULT_CSS = """
    StateTable { height: auto; max-height: 24; padding: 0 1; }
    """

    def __init__(self, layout: StateLayout, **kwargs) -> None:
        super().__init__("waiting for the first estimate", **kwargs)
        self.state_layout = layout
        self.cells: dict[str, tuple[str, str, str]] = {}
        self.border_title = "state"

    def show(self, estimate: Estimate | None) -> None:
        """Show an estimate (None: nothing yet)."""
        if estimate is None:
            return
        rows = state_rows(self.state_layout, estimate.belief)
        self.cells = {r.key: (fmt_value(r.value), fmt_sd(r.sd), r.unit) for r in rows}
        self.update(text_table(("element", "value", "1σ", "unit"), [(k, *v) for k, v in self.cells.items()],
                               right=(False, True, True, False)))
        why = f"update {estimate.sensor}" if estimate.reason == "update" and estimate.sensor else estimate.reason
        self.border_title = f"state at t = {estimate.t:.3f} s ({why})"
