"""The health rule: whether a finished run's estimate can be trusted (DESIGN.md "Health and exit codes").

A run is *degraded* (``fusion run`` exits DEGRADED_EXIT, 4, unless ``--allow-degraded`` or
``health.allow_degraded``) when any of these holds (limits in ``health:``, fusion.health.spec):

- shut out: a measurement sensor's messages not used for more than ``max_unused_share`` (0.5): its share
  dropped as late (of the messages that reached the scheduler well formed) and, of the rest, its share of
  updates rejected, ``1 - (1 - late share) (1 - rejected share)``; a sensor with fewer than
  ``min_messages`` decided messages is not judged by shares;
- locked out: its updates rejected in a row for longer than ``lockout_s`` (default: its recovery's after_s,
  which should have ended the run of rejections), or, without a recovery, to its last update for at least
  2 s, or for more than ``max_unused_share`` of the time between its first and last updates;
- innovations persistently inconsistent: the NIS of its accepted updates, summed over windows of
  ``nis_window_dof`` dof (fusion.health.watch), is chi-square with that many dof for a consistent filter
  (Bar-Shalom, Li and Kirubarajan 2001, sec. 5.4). With K windows in the run, a window is beyond when its
  sum exceeds the chi-square quantile of upper tail ``q = (alpha / K) ** (1 / c)``, and the run is flagged
  when ``c = min(2, K)`` consecutive windows are beyond: on a consistent filter (independent windows) the
  chance of a flag is at most ``K q^c = alpha`` (``nis_false_alarm``, 1e-3). A window must also be over
  ``nis_min_ratio`` (2) per dof: far outside, not only significant. Only too large an NIS flags
  (an overconfident filter or a model that disagrees with the data); a small one is a conservative noise;
- errors against truth (``health.truth``: NEES mean over its dof above 10 by default, with under half the
  estimates' NEES inside their 95 % interval) or agreement with a reference (``health.reference``: attitude
  RMSE above 30 deg by default) beyond a limit.

Each finding names the sensor, the figures and the likely causes in order (fusion.health.causes)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from fusion.chisquare import chi2
from fusion.health import causes
from fusion.health.spec import DEGRADED_EXIT, AgreementLimits, HealthSpec
from fusion.health.watch import DEFAULT_LOCKOUT_S

__all__ = ["Finding", "Verdict", "judge", "nis_windows_beyond", "DEGRADED_EXIT"]

_ORDER = {"shut_out": 0, "locked_out": 1, "nis": 2, "truth": 3, "reference": 4}


@dataclass(frozen=True)
class Finding:
    """One reason the estimate cannot be trusted: ``kind`` (shut_out, locked_out, nis, truth, reference),
    the ``sensor`` it names, the ``figures`` (text) and the likely ``causes``, likeliest first."""

    kind: str
    sensor: str | None
    figures: str
    causes: tuple[str, ...] = ()

    def line(self) -> str:
        who = f"{self.sensor}: " if self.sensor else ""
        told = "; ".join(f"({i}) {c}" for i, c in enumerate(self.causes, 1))
        return f"{who}{self.figures}" + (f"; likely causes, in order: {told}" if told else "")

    def as_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "sensor": self.sensor, "figures": self.figures, "causes": list(self.causes)}


@dataclass(frozen=True)
class Verdict:
    """The rule's judgement of a run: degraded when it has findings (most telling first)."""

    findings: tuple[Finding, ...] = field(default_factory=tuple)

    @property
    def degraded(self) -> bool:
        return bool(self.findings)

    def as_dict(self) -> dict[str, Any]:
        """``{"degraded": bool, "findings": [...]}``: what the summary's ``health`` gets."""
        return {"degraded": self.degraded, "findings": [f.as_dict() for f in self.findings]}

    def line(self) -> str:
        """One line: the first finding, and how many more."""
        if not self.findings:
            return "healthy"
        more = len(self.findings) - 1
        return self.findings[0].line() + (f" (and {more} more finding{'s' * (more > 1)} in the summary's health)"
                                          if more else "")


def judge(summary: dict[str, Any], watch: dict[str, dict[str, Any]] | None = None, spec: HealthSpec | None = None,
          ctx: causes.RunContext | None = None) -> Verdict:
    """The Verdict of a run from its ``summary`` (fusion.run_summary), the ``watch`` report
    (fusion.health.watch.HealthWatch.report; None: judged from the summary alone), the ``spec`` and the
    run's context for the causes (fusion.health.causes.context_of)."""
    spec = spec if spec is not None else HealthSpec()
    ctx = ctx if ctx is not None else causes.RunContext()
    watch = watch or {}
    sensors = list(ctx.sensors) if ctx.sensors else list(watch)
    found: list[Finding] = []
    for name in sensors:
        counts = (summary.get("sensors") or {}).get(name) or {}
        found += _shut_out(name, counts, spec, ctx)
        w = watch.get(name)
        if w is not None:
            found += _locked_out(name, w, spec, ctx)
            found += _nis(name, w, spec, ctx)
    worst = _worst_sensor(summary, sensors)
    found += _agreement("truth", summary.get("errors") or {}, summary.get("consistency") or {}, spec.truth, worst, ctx)
    found += _agreement("reference", summary.get("agreement") or {}, {}, spec.reference, worst, ctx)
    if any(f.kind == "shut_out" for f in found):   # its lock-out says the same thing again
        shut = {f.sensor for f in found if f.kind == "shut_out"}
        found = [f for f in found if not (f.kind == "locked_out" and f.sensor in shut)]
    found.sort(key=lambda f: _ORDER.get(f.kind, 9))
    return Verdict(tuple(found))


def _pct(x: float) -> str:
    return f"{100.0 * x:.0f} %"


def _shut_out(name: str, c: dict[str, Any], spec: HealthSpec, ctx: causes.RunContext) -> list[Finding]:
    late, rejected, used = int(c.get("late", 0)), int(c.get("rejected", 0)), int(c.get("used", 0))
    arrived = int(c.get("received", 0)) - int(c.get("malformed", 0))
    if arrived < spec.min_messages or late + rejected + used < spec.min_messages:
        return []
    late_share = late / arrived if arrived > 0 else 0.0
    decided = used + rejected
    rej_share = rejected / decided if decided else 0.0
    unused = 1.0 - (1.0 - late_share) * (1.0 - rej_share)
    if unused <= spec.max_unused_share:
        return []
    parts = []
    if late:
        parts.append(f"{late:,} of {arrived:,} messages dropped as late ({_pct(late_share)})")
    if rejected or not late:
        parts.append(f"{rejected:,} of {decided:,} updates rejected ({_pct(rej_share)})")
    figures = (f"{', '.join(parts)}: {_pct(unused)} of its messages unused, over the limit "
               f"{_pct(spec.max_unused_share)} (health.max_unused_share)")
    mostly_late = late_share >= rej_share
    return [Finding("shut_out", name, figures, tuple(causes.ordered("shut_out", ctx, name, mostly_late)))]


def _locked_out(name: str, w: dict[str, Any], spec: HealthSpec, ctx: causes.RunContext) -> list[Finding]:
    span_total = (w["last_t"] - w["first_t"]) if w["updates"] > 1 else 0.0
    runs = [(r, "longer than its limit") for r in w["lockouts"]]
    tail = w["tail_rejected"]
    if w["limit_s"] is None and tail is not None and tail[1] >= DEFAULT_LOCKOUT_S and tail[2] >= 3:
        runs.append((tail, "to its last update"))
    longest = w["longest_rejected"]
    if span_total > 0 and longest[1] > spec.max_unused_share * span_total and longest[2] >= 3:
        runs.append((tuple(longest), f"over {_pct(longest[1] / span_total)} of its span"))
    if not runs:
        return []
    (start, span, n), how = max(runs, key=lambda r: r[0][1])
    limit = w["limit_s"]
    told = f" (limit {limit:g} s: {'health.lockout_s' if spec.lockout_s else f'sensors.{name}.recovery.after_s'})" \
        if limit is not None else ""
    figures = f"locked out: {n:,} updates rejected in a row over {span:.1f} s from t {start:.1f} s, {how}{told}"
    return [Finding("locked_out", name, figures, tuple(causes.ordered("locked_out", ctx, name)))]


def nis_windows_beyond(windows: list[tuple[float, float, float, int]], alpha: float,
                       min_ratio: float = 1.0) -> tuple[int, int, float]:
    """The longest run of consecutive NIS windows beyond their chi-square quantile (see the module) and over
    ``min_ratio`` per dof: (its first window's index, its length, the tail probability ``q`` each window was
    tested at); length 0 when none is beyond. ``windows`` are (t first, t last, NIS sum, dof sum)."""
    k = len(windows)
    if k == 0:
        return 0, 0, math.nan
    c = min(2, k)
    q = (alpha / k) ** (1.0 / c)
    best, best_at, run = 0, 0, 0
    cut: dict[int, float] = {}   # the quantile per dof (windows mostly share one)
    for i, (_, _, total, dof) in enumerate(windows):
        if dof not in cut:
            cut[dof] = max(chi2.isf(q, dof), min_ratio * dof)
        run = run + 1 if total > cut[dof] else 0
        if run > best:
            best, best_at = run, i - run + 1
    return best_at, best, q


def _nis(name: str, w: dict[str, Any], spec: HealthSpec, ctx: causes.RunContext) -> list[Finding]:
    windows = w["windows"]
    at, n, q = nis_windows_beyond(windows, spec.nis_false_alarm, spec.nis_min_ratio)
    if n < min(2, len(windows)) or n == 0:
        return []
    sel = windows[at: at + n]
    total, dof = sum(s for _, _, s, _ in sel), sum(d for _, _, _, d in sel)
    figures = (f"innovations inconsistent: NIS {total / dof:.3g} per dof over {n} windows of {spec.nis_window_dof} "
               f"dof, t {sel[0][0]:.1f}-{sel[-1][1]:.1f} s (a consistent filter: 1; each window beyond its "
               f"chi-square quantile at {q:.2g} and {spec.nis_min_ratio:g} per dof, {len(windows)} windows in the "
               f"run, false-alarm rate {spec.nis_false_alarm:g}: health.nis_false_alarm, health.nis_min_ratio)")
    return [Finding("nis", name, figures, tuple(causes.ordered("nis", ctx, name)))]


_LIMITS = (("position_rmse_m", "position RMSE", "m"), ("position_max_m", "position max", "m"),
           ("velocity_rmse_mps", "velocity RMSE", "m/s"), ("attitude_rmse_deg", "attitude RMSE", "deg"),
           ("attitude_max_deg", "attitude max", "deg"))


def _agreement(kind: str, errors: dict[str, Any], consistency: dict[str, Any], limits: AgreementLimits,
               sensor: str | None, ctx: causes.RunContext) -> list[Finding]:
    over = []
    for key, label, unit in _LIMITS:
        limit, value = getattr(limits, key), errors.get(key)
        if limit is not None and isinstance(value, (int, float)) and math.isfinite(value) and value > limit:
            over.append(f"{label} {value:.3g} {unit} > {limit:g} (health.{kind}.{key})")
    nees, dof = consistency.get("nees_mean"), consistency.get("nees_dof")
    inside = consistency.get("nees_in_95_fraction")
    if kind == "truth" and limits.nees_per_dof is not None and nees is not None and dof:
        persistent = not isinstance(inside, (int, float)) or not inside >= limits.nees_inside_min
        if nees / dof > limits.nees_per_dof and persistent:
            told = f", {100 * inside:.0f} % inside its 95 % interval" if isinstance(inside, (int, float)) else ""
            over.append(f"NEES {nees:.4g} on {dof} dof ({nees / dof:.3g} per dof{told}) > {limits.nees_per_dof:g} "
                        "per dof (health.truth.nees_per_dof)")
    if not over:
        return []
    what = "errors against truth" if kind == "truth" else "disagreement with the reference"
    return [Finding(kind, sensor, f"{what}: {', '.join(over)}", tuple(causes.ordered(kind, ctx, sensor)))]


def _worst_sensor(summary: dict[str, Any], sensors: list[str]) -> str | None:
    """The measurement sensor a disagreement most likely comes from: the only one, else the one with the
    largest accepted NIS per dof."""
    if len(sensors) == 1:
        return sensors[0]
    per = (summary.get("consistency") or {}).get("nis_accepted_mean_per_dof") or {}
    scored = [(v, s) for s, v in per.items() if s in sensors and isinstance(v, (int, float))]
    return max(scored)[1] if scored else None
