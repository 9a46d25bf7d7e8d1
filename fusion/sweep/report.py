"""The text summary of a sweep: per variant, means with 95% confidence intervals; paired comparisons
(Wilcoxon signed-rank) between filters and between the values of each varied parameter."""
from __future__ import annotations

import math
from typing import Any, Sequence, TextIO

from .stats import comparisons, summarise

__all__ = ["print_report", "report_metrics", "format_ci", "degraded_counts"]

_MAIN = ("position_rmse_m", "position_max_m", "nees_mean", "nees_in_95_fraction")
_SMOOTH = ("smoothed_position_rmse_m", "smoothed_nees_mean")


def report_metrics(rows: list[dict[str, Any]], smooth: bool) -> list[str]:
    """The metrics shown: the main ones the rows have, NIS means, smoothed ones with --smooth."""
    have = set().union(*(r.keys() for r in rows)) if rows else set()
    ms = [m for m in _MAIN if m in have]
    ms += sorted(k for k in have if k.startswith("nis_mean_"))
    if smooth:
        ms += [m for m in _SMOOTH if m in have]
    return ms


def _is_degraded(row: dict[str, Any]) -> bool:
    v = row.get("degraded")
    return v in (1, True, "1", "True")


def degraded_counts(rows: list[dict[str, Any]], by: Sequence[str]) -> dict[str, int]:
    """Per variant label (as fusion.sweep.stats.summarise names it), its ok trials the health rule judged
    degraded (the ``degraded`` column)."""
    from .stats import _label

    out: dict[str, int] = {}
    for r in rows:
        if r.get("status") == "ok" and _is_degraded(r):
            label = _label(r, by)
            out[label] = out.get(label, 0) + 1
    return out


def format_ci(ci: tuple[float, float, float, int]) -> str:
    m, lo, hi, n = ci
    if not math.isfinite(m):
        return "-"
    if not math.isfinite(lo):
        return f"{m:.4g}"
    return f"{m:.4g} [{lo:.4g}, {hi:.4g}]"


def print_report(rows: list[dict[str, Any]], info: dict, params: Sequence[tuple[str, list[str]]],
                 filters: Sequence[str | None], smooth: bool, out: TextIO) -> None:
    by = (["filter"] if len(filters) > 1 else []) + [f"param.{k}" for k, v in params if len(v) > 1]
    metrics = report_metrics(rows, smooth)
    table = summarise(rows, by, metrics + ["rejected", "wall_s"])
    degraded = degraded_counts(rows, by)
    print("mean [95% CI] over seeds", file=out)
    head = ["variant", "n", "failed", "degraded"] + metrics + ["rejected", "wall_s"]
    print("| " + " | ".join(head) + " |", file=out)
    print("|" + "---|" * len(head), file=out)
    for rec in table:
        cells = [rec["variant"], str(rec["n"]), str(rec["failed"]), str(degraded.get(rec["variant"], 0))]
        cells += [format_ci(rec[m]) for m in head[4:]]
        print("| " + " | ".join(cells) + " |", file=out)
    axes = (["filter"] if len(filters) > 1 else []) + [f"param.{k}" for k, v in params if len(v) > 1]
    cmp_metrics = [m for m in metrics if m in ("position_rmse_m", "position_max_m", "nees_mean",
                                               "smoothed_position_rmse_m")]
    for axis in axes:
        others = [a for a in by if a != axis]
        res = comparisons(rows, axis, others, cmp_metrics)
        if not res:
            continue
        print(f"\npaired by seed along {axis.removeprefix('param.')} (Wilcoxon signed-rank, two-sided)", file=out)
        print("| group | a | b | metric | n | mean a | mean b | median a/b - 1 | a lower | p |", file=out)
        print("|---|---|---|---|---:|---:|---:|---:|---:|---:|", file=out)
        for c in res:
            print(f"| {c['group']} | {c['a']} | {c['b']} | {c['metric']} | {c['n']} | {c['a_mean']:.4g} | "
                  f"{c['b_mean']:.4g} | {100 * c['rel_median']:+.1f}% | {100 * c['a_lower']:.0f}% | {c['p']:.2g} |",
                  file=out)
    if smooth:
        from .stats import paired
        ok = [r for r in rows if r.get("status") == "ok"]
        res = paired([r.get("smoothed_position_rmse_m", math.nan) for r in ok],
                     [r.get("position_rmse_m", math.nan) for r in ok])
        if res.get("n"):
            print(f"\nsmoothed against filtered position RMSE (all variants, paired): {res['a_mean']:.4g} m against "
                  f"{res['b_mean']:.4g} m, median {100 * res['rel_median']:+.1f}%, p = {res['p']:.2g}", file=out)
    if info.get("not_batched"):
        print("\nnot batched: " + "; ".join(sorted(set(info["not_batched"].values()))), file=out)
    bad = [r for r in rows if r.get("status") == "ok" and _is_degraded(r)]
    if bad:
        print(f"\n{len(bad)} of {sum(r.get('status') == 'ok' for r in rows)} trial(s) degraded (the health rule of "
              f"fusion run: an estimate that cannot be trusted); first: seed {bad[0].get('seed')}: "
              f"{bad[0].get('health')}", file=out)
    failed = [r for r in rows if r.get("status") != "ok"]
    if failed:
        print(f"\n{len(failed)} trial(s) failed; first: seed {failed[0].get('seed')}: {failed[0].get('error')}", file=out)
