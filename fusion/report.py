"""Human output of ``fusion run``: the summary table and the replay progress bar (rich).

``print_summary(summary, console=None)``
    Prints the summary dict of DESIGN.md "Outputs" as tables: the run (config, filter, input, duration,
    wall time, x real time, steps, us per predict/update), sensors (received, used, rejected, malformed,
    late, and absorbed when any sensor has some), errors against truth, consistency (NEES, per-sensor NIS with the fraction inside the 95%
    chi-square interval) and any further top-level keys (events, counters). Missing sections are skipped,
    so a summary without truth prints without errors. ``console`` defaults to a rich Console on stdout;
    tests pass ``Console(file=io.StringIO(), width=..)``.

``progress(end_t, enabled=None, *, start_t=None, console=None, delay_s=2.0)``
    A context manager for long replays; it yields a callable ``tick(t)`` (also ``tick.update(t)``) to be
    called with each estimate's time (s)::

        with report.progress(last_timestamp, enabled=show) as tick:
            for est in stream:
                tick(est.t)

    The bar runs from ``start_t`` (default: the first ``t`` ticked) to ``end_t`` (the recording's last
    time stamp; None: no total, the bar shows only the time reached). It appears only after ``delay_s``
    seconds of wall time, so short replays print nothing, and only when ``enabled`` (default: stdout and
    the console are terminals). It is drawn on stderr and is transient: it vanishes when the block ends,
    leaving stdout to the summary. ``tick`` does almost nothing when the bar is hidden and redraws at most
    10 times a second.
"""
from __future__ import annotations

import math
import sys
import time
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any, Iterator

if TYPE_CHECKING:  # rich is imported when something is printed: ``fusion run -q`` never loads it (start-up)
    from rich.console import Console
    from rich.table import Table

__all__ = ["print_summary", "progress", "Ticker"]

_SENSOR_COLUMNS = ("received", "used", "rejected", "malformed", "late")
_ERROR_ROWS = (  # key, label, unit
    ("position_rmse_m", "position RMSE", "m"),
    ("position_max_m", "position max", "m"),
    ("velocity_rmse_mps", "velocity RMSE", "m/s"),
    ("velocity_max_mps", "velocity max", "m/s"),
    ("attitude_rmse_deg", "attitude RMSE", "deg"),
    ("attitude_max_deg", "attitude max", "deg"),
)
_ELEMENT_UNITS = {"p": "m", "v": "m/s"}  # by the block-prefixed element name (px, vy); others vary
_KNOWN = {"config", "filter", "input", "duration_s", "wall_s", "steps", "us_per_predict", "us_per_update",
          "sensors", "errors", "consistency", "not_started"}


def _num(v: Any, fmt: str = ".4g") -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int):
        return f"{v:,}"
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    return format(f, fmt) if math.isfinite(f) else str(f)


def _text(v: Any) -> Any:
    """User or plugin text (a path, a sensor or component name, a value's repr) as a rich ``Text``, shown
    as it is: a string given to rich is read as markup (``br[red]/c.yaml`` would print ``br/c.yaml``)."""
    from rich.text import Text

    return Text(str(v))


def _table(*args: Any, **kwargs: Any) -> Table:
    from rich.table import Table

    return Table(*args, **kwargs)


def _console(**kwargs: Any) -> Console:
    from rich.console import Console

    return Console(**kwargs)


def _kv_table(title: str) -> Table:
    t = _table(title=title, title_justify="left", title_style="bold", show_header=False, box=None,
              pad_edge=False, padding=(0, 2, 0, 0))
    t.add_column(style="cyan", no_wrap=True)
    t.add_column()
    return t


def _run_table(s: dict) -> Table:
    t = _kv_table("Run")
    for key, label in (("config", "config"), ("filter", "filter"), ("input", "input")):
        if key in s:
            t.add_row(label, _text(s[key]))
    dur, wall = s.get("duration_s"), s.get("wall_s")
    if dur is not None:
        t.add_row("duration", f"{_num(dur)} s")
    if wall is not None:
        t.add_row("wall time", f"{_num(wall)} s")
    if dur is not None and wall:
        t.add_row("speed", f"{_num(float(dur) / float(wall), '.1f')} x real time")
    steps = s.get("steps") or {}
    if steps:
        t.add_row("steps", ", ".join(f"{_num(v)} {k}" for k, v in steps.items()))
    for key, label in (("us_per_predict", "per predict"), ("us_per_update", "per update")):
        if s.get(key) is not None:
            t.add_row(label, f"{_num(s[key], '.1f')} us")
    return t


def _sensors_table(sensors: dict) -> Table:
    t = _table(title="Sensors", title_justify="left", title_style="bold")
    t.add_column("sensor", style="cyan")
    # absorbed (fusion.run_stats.ABSORBED: what a decoder dropped, what a solver combined into a fix) only
    # when some sensor has any, so the table adds up: received = used + rejected + malformed + late + absorbed
    columns = _SENSOR_COLUMNS + (("absorbed",) if any(c.get("absorbed") for c in sensors.values()) else ())
    for c in columns:
        t.add_column(c, justify="right")
    for name, c in sensors.items():
        cells = []
        for col in columns:
            v = c.get(col, 0)
            bad = col in ("rejected", "malformed", "late") and v
            cells.append(f"[yellow]{_num(v)}[/]" if bad else _num(v))
        t.add_row(_text(name), *cells)
    return t


def _errors_table(errors: dict) -> Table:
    t = _table(title="Errors against truth", title_justify="left", title_style="bold",
              caption=f"over {errors['samples']:,} estimates" if "samples" in errors else None,
              caption_justify="left")
    t.add_column("metric", style="cyan")
    t.add_column("value", justify="right")
    t.add_column("unit")
    axes = errors.get("position_elements")
    for key, label, unit in _ERROR_ROWS:
        if key in errors:
            if axes and key.startswith("position"):
                label = f"{label} ({' '.join(axes)})"
            t.add_row(_text(label), _num(errors[key]), unit)
    shown = {k for k, _, _ in _ERROR_ROWS} | {"samples", "element_rmse", "position_elements"}
    for name, v in (errors.get("element_rmse") or {}).items():
        t.add_row(_text(f"{name} RMSE"), _num(v), _ELEMENT_UNITS.get(name[:1], ""))
    for key, v in errors.items():
        if key not in shown:
            t.add_row(_text(key), _text(_num(v) if not isinstance(v, dict) else str(v)), "")
    return t


def _consistency_table(c: dict) -> Table:
    t = _table(title="Consistency (95% chi-square interval)", title_justify="left", title_style="bold")
    t.add_column("statistic", style="cyan")
    t.add_column("dof", justify="right")
    t.add_column("mean", justify="right")
    t.add_column("inside 95%", justify="right")
    t.add_column("samples", justify="right")
    if "nees_mean" in c:
        t.add_row("NEES", _num(c.get("nees_dof")), _num(c.get("nees_mean"), ".3g"),
                  _pct(c.get("nees_in_95_fraction")), _num(c.get("nees_samples")))
    frac, dof, n = (c.get(k) or {} for k in ("nis_in_95_fraction", "nis_dof", "nis_samples"))
    rej_mean, rej_n = (c.get(k) or {} for k in ("nis_rejected_mean", "nis_rejected_samples"))
    for sensor, mean in (c.get("nis_mean") or {}).items():
        if sensor not in rej_n:   # a summary without the accepted/rejected split (every update tried)
            t.add_row(_text(f"NIS {sensor}"), _num(dof.get(sensor)), _num(mean, ".3g"), _pct(frac.get(sensor)),
                      _num(n.get(sensor)))
            continue
        # the accepted updates (rejected echoes and mixed dofs would make a 1-dof NIS of 0.76 read
        # "15.4 on 4 dof"); per dof when the dofs differ, then their sum over the sum of dofs (expected 1)
        by_dof = (c.get("nis_accepted_by_dof") or {}).get(sensor)
        if by_dof:
            for d, b in by_dof.items():
                t.add_row(_text(f"NIS {sensor}, dof {d}"), _text(d), _num(b.get("mean"), ".3g"),
                          _pct(b.get("in_95_fraction")), _num(b.get("samples")))
            lo_hi = (c.get("nis_accepted_mean_per_dof_95") or {}).get(sensor) or []
            band = f" ({lo_hi[0]:.3g}-{lo_hi[1]:.3g})" if len(lo_hi) == 2 else ""
            t.add_row(_text(f"NIS {sensor}, all / dof{band}"), "1", _num(
                (c.get("nis_accepted_mean_per_dof") or {}).get(sensor), ".3g"),
                _pct((c.get("nis_accepted_in_95_fraction") or {}).get(sensor)),
                _num((c.get("nis_accepted_samples") or {}).get(sensor)))
        elif sensor in (c.get("nis_accepted_samples") or {}):
            dofs = (c.get("nis_accepted_dofs") or {}).get(sensor) or []
            t.add_row(_text(f"NIS {sensor}"), _num(dofs[0] if dofs else None),
                      _num((c.get("nis_accepted_mean") or {}).get(sensor), ".3g"),
                      _pct((c.get("nis_accepted_in_95_fraction") or {}).get(sensor)),
                      _num((c.get("nis_accepted_samples") or {}).get(sensor)))
        if rej_n.get(sensor):
            t.add_row(_text(f"NIS {sensor}, rejected by the gate"), "-", _num(rej_mean.get(sensor), ".3g"), "-",
                      _num(rej_n.get(sensor)))
    return t


def _pct(v: Any) -> str:
    return "-" if v is None else f"{100.0 * float(v):.1f} %"


def print_summary(summary: dict, console: Console | None = None) -> None:
    """Print ``summary`` (DESIGN.md "Outputs") as readable tables; see the module docstring."""
    from rich.markup import escape

    console = console if console is not None else _console()
    console.print(_run_table(summary))
    if summary.get("sensors"):
        console.print()
        console.print(_sensors_table(summary["sensors"]))
    if summary.get("errors"):
        console.print()
        console.print(_errors_table(summary["errors"]))
    elif summary.get("not_started"):
        console.print(f"\n[bold yellow]{escape(str(summary['not_started']))}[/]")
    elif summary.get("errors") is None:
        console.print("\n[dim]no truth in the input: no errors[/]")
    c = summary.get("consistency") or {}
    if "nees_mean" in c or c.get("nis_mean"):
        console.print()
        console.print(_consistency_table(c))
    for sensor, run in ((summary.get("health") or {}).get("locked_out") or {}).items():
        console.print(f"\n[bold yellow]{escape(str(sensor))}: {run['rejected']} updates in a row rejected over "
                      f"{run['for_s']:.2f} s from t {run['from_s']:.2f} s: a stretch of bad measurements or a "
                      f"filter locked out of them ({(summary.get('health') or {}).get('resets', 0)} recovery "
                      "resets in the run; sensors.NAME.recovery)[/]")
    _print_verdict(summary.get("health") or {}, console)
    extra = {k: v for k, v in summary.items() if k not in _KNOWN}
    if extra:
        console.print()
        t = _kv_table("Other")
        for k, v in extra.items():
            if k == "health" and isinstance(v, dict):   # its findings are printed above
                v = {kk: vv for kk, vv in v.items() if kk != "findings"}
            text = ", ".join(f"{kk}: {_num(vv)}" for kk, vv in v.items()) if isinstance(v, dict) else _num(v)
            t.add_row(_text(k), _text(text))
        console.print(t)


def _print_verdict(health: dict, console: Console) -> None:
    """The health rule's findings (fusion.health: ``degraded`` and ``findings`` in the summary's health),
    each with its figures; the causes are in the summary and on the command's last line."""
    from rich.markup import escape

    if not health.get("degraded"):
        return
    console.print("\n[bold red]degraded: the estimate cannot be trusted[/]")
    for f in health.get("findings") or ():
        who = f"{f.get('sensor')}: " if f.get("sensor") else ""
        console.print(f"[red]  {escape(who + str(f.get('figures', '')))}[/]")


# --------------------------------------------------------------------------- progress
class Ticker:
    """The callable yielded by ``progress``: ``tick(t)`` with the sensor time reached (s)."""

    def __init__(self, end_t: float | None, enabled: bool, start_t: float | None, console: Console | None,
                 delay_s: float):
        self.end_t = end_t
        self.enabled = enabled
        self.start_t = start_t
        self.console = console
        self.delay_s = delay_s
        self.t: float | None = None
        self._wall0 = time.monotonic()
        self._next = self._wall0 + delay_s  # next wall time to look at the bar
        self._bar = None
        self._task = None

    def __call__(self, t: float) -> None:
        self.t = t
        if self.start_t is None:
            self.start_t = t
        if not self.enabled:
            return
        now = time.monotonic()
        if now < self._next:
            return
        self._next = now + 0.1
        if self._bar is None:
            self._start()
        self._bar.update(self._task, completed=self._done(t), reached=f"t = {t:.1f} s")

    update = __call__

    def _done(self, t: float) -> float:
        return max(0.0, t - (self.start_t if self.start_t is not None else t))

    def _start(self) -> None:
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

        total = None
        if self.end_t is not None and self.start_t is not None and self.end_t > self.start_t:
            total = self.end_t - self.start_t
        self._bar = Progress(TextColumn("[bold]replay"), BarColumn(), TextColumn("{task.percentage:>5.1f} %"),
                             TextColumn("{task.fields[reached]}"), TimeElapsedColumn(), TimeRemainingColumn(),
                             console=self.console, transient=True)
        self._task = self._bar.add_task("replay", total=total, reached="")
        self._bar.start()

    @property
    def shown(self) -> bool:
        """Whether the bar has appeared."""
        return self._bar is not None

    def close(self) -> None:
        if self._bar is not None:
            self._bar.stop()


@contextmanager
def progress(end_t: float | None, enabled: bool | None = None, *, start_t: float | None = None,
             console: Console | None = None, delay_s: float = 2.0) -> Iterator[Ticker]:
    """A progress bar for a replay up to sensor time ``end_t`` (s); see the module docstring."""
    if enabled is None:
        console = console if console is not None else _console(stderr=True)
        enabled = sys.stdout.isatty() and console.is_terminal
    elif enabled and console is None:
        console = _console(stderr=True)
    ticker = Ticker(end_t, bool(enabled), start_t, console, delay_s)
    try:
        yield ticker
    finally:
        ticker.close()
