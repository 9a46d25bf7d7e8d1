"""Human output of a smoothed run: filtered and smoothed errors side by side (``fusion run --smooth``)."""
from __future__ import annotations

from typing import Any

from rich.console import Console
from rich.table import Table

__all__ = ["print_smoothed", "comparison_rows"]

_ROWS = (  # section, key, label, unit
    ("errors", "position_rmse_m", "position RMSE", "m"),
    ("errors", "position_max_m", "position max", "m"),
    ("errors", "velocity_rmse_mps", "velocity RMSE", "m/s"),
    ("errors", "velocity_max_mps", "velocity max", "m/s"),
    ("errors", "attitude_rmse_deg", "attitude RMSE", "deg"),
    ("errors", "attitude_max_deg", "attitude max", "deg"),
    ("consistency", "nees_mean", "NEES mean", ""),
    ("consistency", "nees_in_95_fraction", "NEES in 95% interval", ""),
)


def comparison_rows(summary: dict[str, Any]) -> list[tuple[str, str, float, float]]:
    """``(label, unit, filtered, smoothed)`` for every statistic both have."""
    sm = summary.get("smoothed") or {}
    rows = []
    for section, key, label, unit in _ROWS:
        a = (summary.get(section) or {}).get(key)
        b = (sm.get(section) or {}).get(key)
        if a is not None and b is not None:
            rows.append((label, unit, float(a), float(b)))
    return rows


def print_smoothed(summary: dict[str, Any], console: Console | None = None) -> None:
    """The comparison table and a line on the smoother (nodes, backward time, store)."""
    console = console if console is not None else Console()
    sm = summary.get("smoothed")
    if not sm:
        return
    lag = f", lag {sm['lag_s']:g} s" if "lag_s" in sm else ""
    store = sm.get("store") or {}
    disk = f", {store.get('bytes_on_disk', 0) / 1e6:.1f} MB on disk" if store.get("on_disk") else ""
    console.print()
    console.print(f"smoother: {sm.get('smoother')} ({sm.get('filter')}{lag}), {sm.get('nodes', 0):,} nodes, "
                  f"backward {sm.get('backward_wall_s', 0.0):.2f} s against forward "
                  f"{sm.get('forward_wall_s', 0.0):.2f} s{disk}", markup=False)  # plugin names, shown as they are
    rows = comparison_rows(summary)
    if not rows:
        console.print("[dim]no truth in the input: no errors to compare[/]")
        return
    t = Table(title="Filtered and smoothed", title_justify="left")
    for col, just in (("", "left"), ("filtered", "right"), ("smoothed", "right"), ("change", "right")):
        t.add_column(col, justify=just)
    for label, unit, a, b in rows:
        change = f"{100.0 * (b - a) / a:+.1f}%" if a and "NEES" not in label else ""
        u = f" {unit}" if unit else ""
        t.add_row(label, f"{a:.4g}{u}", f"{b:.4g}{u}", change)
    console.print(t)
