"""The health panel: per sensor its rate against the expected rate (Hz), the time since its last accepted
measurement against its limit (s), its gap and clock events and its status; then the filter events
(covariance repairs, resets, clock events) and the overall state with its reason."""
from __future__ import annotations

import math

from rich.text import Text
from textual.widgets import Static

from fusion.tui.health import Health
from fusion.tui.text_table import text_table

STATE_STYLE = {"OK": "bold green", "DEGRADED": "bold yellow", "LOST": "bold red"}
_ROW_STYLE = {"ok": None, "waiting": "dim", "slow": "yellow", "stale": "bold yellow"}
# rejected, malformed and late are in the sensors panel beside this one
HEADERS = ("sensor", "Hz", "exp", "ok ago", "limit", "gap", "clk", "status")  # Hz; s since accepted; s


def _f(v: float, fmt: str) -> str:
    return "-" if v != v else ("inf" if math.isinf(v) else format(v, fmt))


class HealthPanel(Static):
    """``rows`` holds the texts of each sensor's row by sensor name (for tests)."""

    DEFAULT_CSS = """
    HealthPanel { height: auto; padding: 0 1; }
    """

    def __init__(self, **kwargs) -> None:
        super().__init__("no messages yet", **kwargs)
        self.border_title = "health"
        self.rows: dict[str, tuple[str, ...]] = {}
        self.state = ""

    def show(self, health: Health | None) -> None:
        if health is None:
            return
        rows, styles = {}, []
        for s in health.sensors:
            c = s.counts
            rows[s.name] = (s.name, _f(s.rate, ".1f"), _f(s.expected, ".1f"), _f(s.since_ok, ".2f"),
                            _f(s.limit, ".3g"), str(c.get("gap", 0)), str(c.get("clock", 0)), s.status)
            styles.append(_ROW_STYLE.get(s.status))
        self.rows = rows
        out = text_table(HEADERS, list(rows.values()), right=(False, *([True] * 6), False), styles=styles)
        out.append(f"\nfilter: {health.repairs} repairs  {health.resets} resets  {health.clock} clock events\n")
        out.append(f" {health.state} ", style="reverse " + STATE_STYLE.get(health.state, "bold"))
        out.append(f" {health.reason}")
        self.state = health.state
        self.border_title = f"health: {health.state}"
        self.update(out)
