"""Tables and text of docs/results/uwb.md from the runs of experiments/uwb_ukf_vs_ekf.py."""
from __future__ import annotations

import math
import platform
from pathlib import Path
from typing import Any

import numpy as np

from uwb_cases import AFTER_S, INIT_S, NEAR_M, paired

METRIC = {
    "rmse_all": "RMSE, whole run", "max_all": "max, whole run", "rmse_steady": "RMSE, steady",
    "rmse_man": "RMSE, during manoeuvres", "max_man": "max, during manoeuvres",
    "rmse_after": f"RMSE, {AFTER_S:g} s after manoeuvres", "max_after": f"max, {AFTER_S:g} s after manoeuvres",
    "rmse_init": f"RMSE, first {INIT_S:g} s", "max_init": f"max, first {INIT_S:g} s",
    "rmse_settled": f"RMSE after {INIT_S:g} s", "max_settled": f"max after {INIT_S:g} s",
    "rmse_near": f"RMSE, within {NEAR_M:g} m of a beacon", "nees_mean": "mean NEES (4 dof: 4 if consistent)",
}


def f3(v: float) -> str:
    if v is None or not np.isfinite(v):
        return "n/a"
    return f"{v:.3f}" if abs(v) < 100 else f"{v:.0f}"


def pct(v: float) -> str:
    return "n/a" if v is None or not np.isfinite(v) else f"{100 * v:+.1f}%"


def pval(p: float) -> str:
    if p is None or not np.isfinite(p):
        return "n/a"
    return f"{p:.2g}" if p >= 1e-4 else "<1e-4"


def stats(rows: list[dict], metric: str) -> dict[str, Any]:
    return paired(rows, metric)


def verdict(st: dict[str, Any], alpha: float = 0.01) -> str:
    """'UKF lower', 'UKF higher' or 'no difference' at two-sided level alpha (Wilcoxon)."""
    if not st.get("n"):
        return "n/a"
    if st["p"] >= alpha:
        return "no significant difference"
    return "UKF lower" if st["rel_median"] < 0 else "UKF higher"


def paired_table(rows_by_case: dict[str, list[dict]], cases, metrics: list[str]) -> list[str]:
    """One line per case and metric: both means (sd over seeds), the relative paired difference, the share
    of seeds where the UKF is lower and the Wilcoxon p-value."""
    out = ["| case | metric | UKF mean (sd) | EKF mean (sd) | UKF/EKF - 1: median [quartiles] | UKF lower | p |",
           "|---|---|---|---|---|---|---|"]
    for c in cases:
        rows = rows_by_case[c.name]
        for m in metrics:
            st = stats(rows, m)
            if not st.get("n"):
                continue
            out.append(f"| {c.label or c.name} | {METRIC.get(m, m)} | {f3(st['ukf_mean'])} ({f3(st['ukf_sd'])}) | "
                       f"{f3(st['ekf_mean'])} ({f3(st['ekf_sd'])}) | {pct(st['rel_median'])} "
                       f"[{pct(st['rel_q1'])}, {pct(st['rel_q3'])}] | {round(100 * st['ukf_better'])}% of {st['n']} | "
                       f"{pval(st['p'])} |")
    return out


LOST_M = 1.0   # m: an error above this after the first INIT_S s (ten times the range noise) is a lost track


def lost(rows: list[dict], flt: str) -> list[int]:
    """Seeds whose error exceeded LOST_M after the first INIT_S seconds."""
    return [r["seed"] for r in rows if r[flt]["max_settled"] > LOST_M]


def cases_table(rows_by_case: dict[str, list[dict]], cases, metrics: list[str]) -> list[str]:
    """Paper-style: per case and filter, mean (sd over seeds) of each metric, m, and the lost runs."""
    head = ("| case | filter | " + " | ".join(METRIC[m] for m in metrics) +
            f" | runs with an error > {LOST_M:g} m after {INIT_S:g} s |")
    out = [head, "|" + "---|" * (len(metrics) + 3)]
    for c in cases:
        rows = rows_by_case[c.name]
        for flt in ("ukf", "ekf"):
            cells = []
            for m in metrics:
                v = np.array([r[flt][m] for r in rows], float)
                cells.append(f"{f3(np.nanmean(v))} ({f3(np.nanstd(v, ddof=1))})")
            out.append(f"| {c.label} | {flt.upper()} | " + " | ".join(cells) + f" | {len(lost(rows, flt))}/{len(rows)} |")
    return out


def collinear_table(rows_by_case: dict[str, list[dict]], cases) -> list[str]:
    out = ["| case | filter | ended on the mirror side | ended at the line | time on the mirror side | "
           "time at the line | runs warned by `check` | runs that went wrong, warned before | RMSE median (m) | "
           "ranges rejected (mean) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for c in cases:
        rows = rows_by_case[c.name]
        for flt in ("ukf", "ekf"):
            m = [r[flt] for r in rows]
            ends = np.array([x["mirror_end"] for x in m])
            lends = np.array([x["line_end"] for x in m])
            frac = np.array([x["mirror_fraction"] for x in m])
            lfrac = np.array([x["line_fraction"] for x in m])
            warned = np.array([x["warned"] for x in m])
            bad = (frac > 0) | (lfrac > 0)
            early = np.array([x.get("warn_t", np.inf) <= x.get("bad_t", np.inf) for x in m])
            mw = f"{int((early & bad).sum())}/{int(bad.sum())}" if bad.any() else "-"
            out.append(f"| {c.label} | {flt.upper()} | {int(ends.sum())}/{len(m)} | {int(lends.sum())}/{len(m)} | "
                       f"{100 * frac.mean():.1f}% | {100 * lfrac.mean():.1f}% | {int(warned.sum())}/{len(m)} | {mw} | "
                       f"{np.median([x['rmse_all'] for x in m]):.3f} | {np.mean([x['rejected'] for x in m]):.1f} |")
    return out


def process_noise_table(rows_by_case: dict[str, list[dict]], cases) -> list[str]:
    groups: dict[float, list] = {}
    for c in cases:
        groups.setdefault(float(c.config["process"]["spectral_density"]), []).append(c)
    names = [c.label.split(", ", 1)[1] for c in next(iter(groups.values()))]
    out = ["| S (m^2/s^3) | " + " | ".join(names) + " | mean of the four | UKF/EKF - 1 (median of all runs) |",
           "|---" * (len(names) + 3) + "|"]
    for S, cs in sorted(groups.items()):
        cells, allu, rel = [], [], []
        for c in cs:
            rows = rows_by_case[c.name]
            u = np.array([r["ukf"]["rmse_all"] for r in rows])
            e = np.array([r["ekf"]["rmse_all"] for r in rows])
            rej = np.mean([r["ukf"]["rejected"] for r in rows])
            cells.append(f"{np.mean(u):.3f} (max {np.max(u):.2f}{f', {rej:.0f} rejected' if rej >= 1 else ''})")
            allu.append(np.mean(u))
            rel.extend(u / e - 1)
        out.append(f"| {S:g} | " + " | ".join(cells) + f" | {np.mean(allu):.3f} | {pct(float(np.median(rel)))} |")
    return out


def summarize_results(studies, results) -> dict[str, Any]:
    """Paired statistics of every study, case and metric (docs/results/uwb/summary.json)."""
    out: dict[str, Any] = {}
    for st in studies:
        out[st.key] = {}
        for c in st.cases:
            rows = results[st.key][c.name]
            keys = sorted({k for r in rows[:1] for k, v in r["ukf"].items() if isinstance(v, (int, float, bool))})
            d = {}
            for m in keys:
                u = np.array([float(r["ukf"][m]) for r in rows])
                e = np.array([float(r["ekf"][m]) for r in rows])
                d[m] = {"ukf_mean": float(np.nanmean(u)) if np.isfinite(u).any() else None,
                        "ekf_mean": float(np.nanmean(e)) if np.isfinite(e).any() else None}
                if m.startswith(("rmse", "max", "nees")):
                    d[m].update({k: v for k, v in paired(rows, m).items()})
            out[st.key][c.name] = {"label": c.label, "n": len(rows), "metrics": d,
                                   "lost": {f: lost(rows, f) for f in ("ukf", "ekf")}}
            if "mirror_fraction" in rows[0]["ukf"]:
                wf = {}
                for f in ("ukf", "ekf"):
                    bad = [r[f] for r in rows if r[f]["mirror_fraction"] > 0 or r[f]["line_fraction"] > 0]
                    wf[f] = (sum(x.get("warn_t", math.inf) <= x.get("bad_t", math.inf) for x in bad), len(bad))
                out[st.key][c.name]["warned_first"] = wf
    return out


class Facts:
    """Look-ups into the summary: ``s(study, case, metric)`` is the paired statistics dict."""

    def __init__(self, summary: dict[str, Any]):
        self.summary = summary

    def s(self, study: str, case: str, metric: str) -> dict[str, Any]:
        return self.summary[study][case]["metrics"][metric]

    def mean(self, study, case, metric, flt="ukf") -> float:
        return self.s(study, case, metric)[f"{flt}_mean"]

    def rel(self, study, case, metric) -> str:
        return _pct(self.s(study, case, metric)["rel_median"])

    def lost(self, study, case, flt) -> list[int]:
        return self.summary[study][case]["lost"][flt]

    def n(self, study, case) -> int:
        return self.summary[study][case]["n"]

    def cmp(self, study, case, metric, unit="m") -> str:
        """'UKF 0.119 m, EKF 0.121 m: median paired difference -1.2%, UKF lower in 45 of 50 seeds, p = 1e-5'."""
        st = self.s(study, case, metric)
        u = "" if not unit else f" {unit}"
        return (f"UKF {_n(st['ukf_mean'])}{u}, EKF {_n(st['ekf_mean'])}{u}: median paired difference "
                f"{_pct(st['rel_median'])}, UKF lower in {round(st['ukf_better'] * st['n'])} of {st['n']} seeds, "
                f"p {_p(st['p'])}")

    def verdict(self, study, case, metric, alpha=0.01) -> str:
        st = self.s(study, case, metric)
        if st["p"] >= alpha:
            return "no significant difference"
        return "UKF lower" if st["rel_median"] < 0 else "UKF higher"

    def max_abs_rel(self, study, metric) -> float:
        return max(abs(c["metrics"][metric]["rel_median"]) for c in self.summary[study].values()
                   if metric in c["metrics"] and "rel_median" in c["metrics"][metric])


def _n(v: float) -> str:
    if v is None or not np.isfinite(v):
        return "n/a"
    return f"{v:.3f}" if abs(v) < 10 else f"{v:.1f}"


def _p(p: float) -> str:
    return f"= {p:.1g}" if p >= 1e-4 else "< 1e-4"


def _pct(v: float) -> str:
    return f"{100 * v:+.2f}%" if abs(v) < 1e-3 else f"{100 * v:+.1f}%"


def _ends(F: Facts, case: str) -> str:
    """'UKF 20 of 50 runs ended on the mirror side and 18 on the line, EKF 16 and 0'."""
    c = F.summary["collinear"][case]["metrics"]
    n = F.summary["collinear"][case]["n"]
    k = {f: (round(c["mirror_end"][f"{f}_mean"] * n), round(c["line_end"][f"{f}_mean"] * n)) for f in ("ukf", "ekf")}
    return (f"of {n} runs the UKF ended {k['ukf'][0]} on the mirror side and {k['ukf'][1]} at the line, "
            f"the EKF {k['ekf'][0]} and {k['ekf'][1]}")


def _lost_sentence(F: Facts, study: str) -> str:
    cs = F.summary[study]
    lu = {c: set(v["lost"]["ukf"]) for c, v in cs.items()}
    le = {c: set(v["lost"]["ekf"]) for c, v in cs.items()}
    nu, ne = sum(map(len, lu.values())), sum(map(len, le.values()))
    if not nu and not ne:
        return "No run went off by more than 1 m after the first 5 s."
    same = all(lu[c] == le[c] for c in cs)
    return (f"{nu} UKF and {ne} EKF runs of {sum(v['n'] for v in cs.values())} went off by more than 1 m after "
            f"the first 5 s (last column){', the same runs for both filters' if same else ''}.")


def _warned_first(F: Facts) -> str:
    tot = first = 0
    for case in F.summary["collinear"].values():
        w = case.get("warned_first", {})
        for f in ("ukf", "ekf"):
            tot += w.get(f, (0, 0))[1]
            first += w.get(f, (0, 0))[0]
    return f"{first} of {tot}"


def write_page(out: Path, studies, results, figures: dict[str, str], n_seeds: int, wall: float, jobs: int
               ) -> dict[str, Any]:
    from uwb_text import page

    summary = summarize_results(studies, results)
    by_key = {s.key: s for s in studies}
    tables = {
        "cases": cases_table(results["cases"], by_key["cases"].cases,
                             ["rmse_all", "max_settled", "rmse_man", "max_man", "rmse_after", "max_after"]),
        "vector": cases_table(results["vector"], by_key["vector"].cases,
                              ["rmse_all", "max_settled", "rmse_man", "max_man", "rmse_after", "max_after"]),
        "vector_paired": paired_table(results["vector"], by_key["vector"].cases,
                                      ["rmse_all", "rmse_settled", "rmse_man", "rmse_after", "nees_mean"]),
        "cases_paired": paired_table(results["cases"], by_key["cases"].cases,
                                     ["rmse_all", "rmse_settled", "max_settled", "rmse_steady", "rmse_man",
                                      "max_man", "rmse_after", "max_after", "nees_mean"]),
        "process_noise": process_noise_table(results["process_noise"], by_key["process_noise"].cases),
        "collinear": collinear_table(results["collinear"], by_key["collinear"].cases),
    }
    for key in ("initial", "rate", "close", "matched", "alpha"):
        tables[key] = paired_table(results[key], by_key[key].cases, by_key[key].metrics)
    env = {"seeds": n_seeds, "tune_seeds": by_key["process_noise"].seeds, "wall_s": wall, "jobs": jobs,
           "python": platform.python_version(), "numpy": np.__version__,
           "runs": sum(len(r) for per in results.values() for r in per.values())}
    text = page(tables, summary, figures, env, studies)
    out.write_text(text)
    keep = {s.key: set(s.metrics) for s in studies}
    compact = {key: {name: {"label": c["label"], "n": c["n"], "lost": c["lost"],
                            "metrics": {m: {k: (round(v, 6) if isinstance(v, float) else v) for k, v in st.items()}
                                        for m, st in c["metrics"].items() if m in keep[key]}}
                     for name, c in per.items()} for key, per in summary.items()}
    return {"env": env, "studies": compact}
