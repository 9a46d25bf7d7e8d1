"""Statistics over the seeds of a sweep: per-variant means with 95% confidence intervals (Student t)
and paired comparisons (two filters, or two values of a parameter, on the same seeds) by the Wilcoxon
signed-rank test (scipy.stats), as docs/results/uwb.md reports them."""
from __future__ import annotations

import math
from collections import defaultdict
from typing import Any, Sequence

import numpy as np

__all__ = ["mean_ci", "summarise", "paired", "comparisons"]


def mean_ci(values: Sequence[float], level: float = 0.95) -> tuple[float, float, float, int]:
    """(mean, lower, upper, n) of the finite values; the t interval of the mean (nan bounds for n < 2)."""
    from scipy import stats

    v = np.asarray([x for x in values if isinstance(x, (int, float)) and math.isfinite(x)], float)
    n = v.size
    if n == 0:
        return math.nan, math.nan, math.nan, 0
    m = float(v.mean())
    if n < 2:
        return m, math.nan, math.nan, n
    h = float(stats.t.ppf(0.5 + level / 2, n - 1) * v.std(ddof=1) / math.sqrt(n))
    return m, m - h, m + h, n


def _label(row: dict[str, Any], by: Sequence[str]) -> str:
    return ", ".join(f"{k.removeprefix('param.')}={row.get(k)}" if k.startswith("param.") else str(row.get(k))
                     for k in by) or "all"


def summarise(rows: list[dict[str, Any]], by: Sequence[str], metrics: Sequence[str]) -> list[dict[str, Any]]:
    """One record per variant (the values of the columns ``by``): n, failed, and for each metric its
    mean and 95% CI ``(mean, lo, hi)``."""
    groups: dict[str, list] = defaultdict(list)
    for r in rows:
        groups[_label(r, by)].append(r)
    out = []
    for label, rs in groups.items():
        ok = [r for r in rs if r.get("status") == "ok"]
        rec: dict[str, Any] = {"variant": label, "n": len(ok), "failed": len(rs) - len(ok)}
        for m in metrics:
            rec[m] = mean_ci([r.get(m, math.nan) for r in ok])
        out.append(rec)
    return out


def paired(a: Sequence[float], b: Sequence[float]) -> dict[str, Any]:
    """Paired comparison of a against b (same seeds): n, means, median relative difference a/b - 1, the
    fraction of pairs where a is lower, and the two-sided Wilcoxon signed-rank p (1.0 when all equal)."""
    from scipy.stats import wilcoxon

    a, b = np.asarray(a, float), np.asarray(b, float)
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    if a.size == 0:
        return {"n": 0}
    d = a - b
    try:
        p = float(wilcoxon(a, b).pvalue) if np.any(d != 0) else 1.0
    except ValueError:
        p = 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = float(np.median(a / b - 1.0))
    return {"n": int(a.size), "a_mean": float(a.mean()), "b_mean": float(b.mean()), "rel_median": rel,
            "a_lower": float(np.mean(d < 0)), "p": p}


def comparisons(rows: list[dict[str, Any]], axis: str, others: Sequence[str], metrics: Sequence[str]) -> list[dict]:
    """Paired comparisons along ``axis`` (``filter`` or a ``param.<key>`` column): within each group of
    the ``others`` columns, every pair of values of ``axis`` (the first value seen against each later one),
    paired by seed."""
    ok = [r for r in rows if r.get("status") == "ok"]
    values = list(dict.fromkeys(r.get(axis) for r in ok))
    if len(values) < 2:
        return []
    out = []
    groups: dict[str, dict] = defaultdict(lambda: defaultdict(dict))
    for r in ok:
        groups[_label(r, others)][r.get(axis)][r["seed"]] = r
    for g, by_val in groups.items():
        for i, va in enumerate(values):
            for vb in values[i + 1:]:
                A, B = by_val.get(va, {}), by_val.get(vb, {})
                seeds = sorted(set(A) & set(B))
                for m in metrics:
                    res = paired([A[s].get(m, math.nan) for s in seeds], [B[s].get(m, math.nan) for s in seeds])
                    if res.get("n"):
                        out.append({"group": g, "axis": axis.removeprefix("param."), "a": va, "b": vb, "metric": m,
                                    **res})
    return out
