"""The health rule's false-alarm rate on clean runs, and how near its limits clean runs come
(docs/results/health.md): every shipped config that has a scenario is run over ``--seeds`` freshly simulated
recordings (seeds 1000..), as a sweep trial runs it (fusion.sweep.trial), with the health watch, and judged.

    python experiments/health_false_alarm.py --seeds 30 -o docs/results/health.md

Per config: the trials flagged, and the largest over its unflagged trials of each test's statistic over its
limit (1 would flag): the unused share of a sensor over max_unused_share, the NIS of the second-worst of
two consecutive windows over its threshold (its chi-square quantile or nis_min_ratio per dof), the NEES per
dof over truth.nees_per_dof.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def margins(summary: dict, report: dict, spec) -> tuple[float, float, float]:
    """(unused share / limit, worst consecutive-pair NIS window / quantile, NEES per dof / limit)."""
    from fusion.chisquare import chi2

    unused = 0.0
    for name in report:
        c = summary["sensors"].get(name, {})
        arrived = c.get("received", 0) - c.get("malformed", 0)
        decided = c.get("used", 0) + c.get("rejected", 0)
        if arrived >= spec.min_messages:
            late = c.get("late", 0) / arrived
            rej = c.get("rejected", 0) / decided if decided else 0.0
            unused = max(unused, (1 - (1 - late) * (1 - rej)) / spec.max_unused_share)
    nis = 0.0
    for rep in report.values():
        w = rep["windows"]
        if not w:
            continue
        c = min(2, len(w))
        q = (spec.nis_false_alarm / len(w)) ** (1 / c)
        ratios = [s / max(chi2.isf(q, d), spec.nis_min_ratio * d) for _, _, s, d in w]
        pairs = [min(ratios[i:i + c]) for i in range(len(ratios) - c + 1)]
        nis = max(nis, max(pairs))
    cons = summary.get("consistency") or {}
    nees = 0.0
    if cons.get("nees_mean") is not None and cons.get("nees_dof") and spec.truth.nees_per_dof:
        nees = cons["nees_mean"] / cons["nees_dof"] / spec.truth.nees_per_dof
    return unused, nis, nees


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("-o", "--output", default=None, help="write the markdown page there")
    args = ap.parse_args()
    from fusion import pipeline
    from fusion.health import HealthWatch, assess, spec_of
    from fusion.sweep.grid import default_scenario
    from fusion.sweep.trial import Trial, recording_of, system_of, with_initial

    lines = ["| config | scenario | trials | degraded | max unused / limit | max NIS pair / quantile | "
             "max NEES / limit |", "|---|---|---:|---:|---:|---:|---:|"]
    total = flagged = 0
    flags: list[str] = []
    inputs: list[str] = []   # the configs and scenarios run: the page's provenance block (experiments/provenance.py)
    for config in sorted((ROOT / "configs").glob("*.yaml")):
        try:
            scenario = default_scenario(str(config))
        except Exception:
            continue   # an imported-log config (px4, ardupilot): judged on its recordings by tests/health
        inputs += [str(config.relative_to(ROOT)), str(Path(scenario).resolve().relative_to(ROOT))]
        worst = [0.0, 0.0, 0.0]
        bad = 0
        rmse: list[float] = []
        flagged_rows: list[tuple[int, float, str]] = []
        for seed in range(1000, 1000 + args.seeds):
            trial = Trial(str(config), scenario, seed)
            lines_ = recording_of(trial)
            system = with_initial(system_of(trial), trial, lines_)
            watch = HealthWatch(system, spec_of(system))
            result = pipeline.run(system, lines_, [watch], hooks=False)
            verdict = assess(system, result.summary, watch, result.parsed.header, lines_)
            bad += verdict.degraded
            err = (result.summary.get("errors") or {}).get("position_rmse_m", float("nan"))
            if verdict.degraded:
                print(f"{config.name} seed {seed}: {verdict.line()}", file=sys.stderr)
                flagged_rows.append((seed, err, "; ".join(f"{f.sensor}: {f.figures.split(' (')[0]}"
                                                          for f in verdict.findings)))
            else:
                rmse.append(err)
            if not verdict.degraded:
                worst = [max(a, b) for a, b in zip(worst, margins(result.summary, watch.report(), spec_of(system)))]
        total, flagged = total + args.seeds, flagged + bad
        lines.append(f"| {config.name} | {Path(scenario).name} | {args.seeds} | {bad} | "
                     + " | ".join(f"{v:.2f}" for v in worst) + " |")
        print(lines[-1], flush=True)
        typical = sorted(rmse)[len(rmse) // 2] if rmse else float("nan")
        flags += [f"- {config.name} seed {seed}: position RMSE {e:.3g} m (the median of its unflagged trials: "
                  f"{typical:.3g} m); {what}" for seed, e, what in flagged_rows]
    lines.append(f"| all | | {total} | {flagged} | | | |")
    text = ("# Health rule: false alarms on clean runs\n\nMade by `python experiments/health_false_alarm.py "
            f"--seeds {args.seeds} -o docs/results/health.md`: every shipped config with a scenario, one freshly "
            "simulated recording a seed (seeds 1000 on), run as a sweep trial with the health watch and judged "
            "by the rule of `fusion run` (fusion/health, docs/health.md). A degraded trial here is a false "
            "alarm, unless the filter did fail on it (listed below the table with its error). The last three "
            "columns are the largest, over the unflagged trials, of each test's statistic over its limit (1 "
            "flags): a sensor's unused share over `max_unused_share`; the smaller NIS window sum of the worst "
            "two consecutive windows over its threshold (chi-square quantile or `nis_min_ratio`); the NEES per "
            "dof over `truth.nees_per_dof`.\n\n" + "\n".join(lines) + "\n")
    if flags:
        text += ("\nThe flagged trials, with their position error against the typical one of their config (a "
                 "flagged trial whose error is many times the typical one is a filter that failed on clean data, "
                 "found, not a false alarm):\n\n" + "\n".join(flags) + "\n")
    if args.output:
        sys.path.insert(0, str(ROOT / "experiments"))
        import provenance

        provenance.write_page(args.output, text, inputs)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
