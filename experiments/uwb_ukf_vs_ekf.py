#!/usr/bin/env python3
"""Paper 001, UKF against EKF, reproduced over many seeds: regenerates docs/results/uwb.md and its figures.

    python experiments/uwb_ukf_vs_ekf.py                 # everything, 50 seeds a case (~10 min on 2 cores)
    python experiments/uwb_ukf_vs_ekf.py --seeds 12      # a quick look (the page says how many seeds)
    python experiments/uwb_ukf_vs_ekf.py --jobs 4 --out /tmp/uwb.md

Every run simulates a recording with ``fusion.simulate`` (the shipped scenarios scenarios/uwb_route*.yaml
with the seed of the run, plus the overrides of the case) in a temporary folder and replays it through the
shipped configs (configs/uwb_pv_ukf*.yaml) once with ``ukf`` and once with ``ekf``: the two filters see
the same ranges, so the comparison pairs by seed (experiments/uwb_cases.py). Tables, figures and the text
of docs/results/uwb.md are written by experiments/uwb_report.py and experiments/uwb_figures.py.
"""
from __future__ import annotations

import argparse
import json
import os
import pickle
import sys
import tempfile
import time
from dataclasses import dataclass, field
from multiprocessing import Pool
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from uwb_cases import ROOT, Case, run_pair  # noqa: E402

OPTIMAL = {"B1": [0.0, 0.0], "B2": [30.0, 0.0], "B3": [30.0, 20.0], "B4": [0.0, 20.0]}
SMALL = {"B1": [12.0, 7.0], "B2": [18.0, 7.0], "B3": [18.0, 13.0], "B4": [12.0, 13.0]}


def close_beacons(d: float) -> dict[str, list[float]]:
    """Beacons around the area, each ``d`` m beside the middle of one leg of route 1 (it passes all four)."""
    return {"B1": [15.0, 3.0 - d], "B2": [27.0 + d, 10.0], "B3": [8.0, 17.0 + d], "B4": [3.0 - d, 10.0]}


@dataclass
class Study:
    key: str
    title: str
    cases: list[Case]
    metrics: list[str]
    seeds: int | None = None            # None: the --seeds of the command
    keep_errors: bool = False
    note: str = ""
    extra: dict = field(default_factory=dict)


def rate(r: float) -> dict:
    return {"sensors": {"uwb": {"rate_hz": r}}}


def studies(n_tune: int) -> list[Study]:
    """Every study of the page (what each varies; the rest is the shipped config and scenario)."""
    drawn = "drawn"
    out = [Study("cases", "The four cases of the paper (as shipped)", [
        Case("route1_optimal", "route1", "optimal", initial=drawn, label="route 1, optimal"),
        Case("route1_line", "route1", "line", initial=drawn, label="route 1, collinear"),
        Case("route2_optimal", "route2", "optimal", initial=drawn, label="route 2, optimal"),
        Case("route2_line", "route2", "line", initial=drawn, label="route 2, collinear")],
        ["rmse_all", "max_all", "rmse_steady", "rmse_man", "max_man", "rmse_after", "max_after", "nees_mean"],
        keep_errors=True)]
    vec = {"sensors": {"uwb": {"spacing_s": 0.001}}}
    out.append(Study("vector", "The four cases with the paper's vector update (eq. 6: four ranges at once)", [
        Case(f"{r}_{lay}_vector", r, lay, initial=drawn, scenario=vec, vector=True,
             label=f"{r.replace('route', 'route ')}, {'optimal' if lay == 'optimal' else 'collinear'}, vector")
        for r in ("route1", "route2") for lay in ("optimal", "line")],
        ["rmse_all", "rmse_settled", "rmse_man", "rmse_after", "nees_mean"]))
    out.append(Study("process_noise", "Process noise S (tuning; both filters the same S)", [
        Case(f"S{S}_{r}_{lay}", r, lay, initial=drawn, config={"process": {"spectral_density": S}},
             label=f"S = {S:g}, {r.replace('route', 'route ')}, {lay}")
        for S in (0.05, 0.1, 0.2, 0.5, 1.0) for r in ("route1", "route2") for lay in ("optimal", "line")],
        ["rmse_all", "rmse_after", "max_after"], seeds=n_tune,
        note="fewer seeds: it only chooses S"))
    out.append(Study("initial", "Initial uncertainty (route 1, optimal, first 15 s)", [
        Case(f"init{sd:g}{'_nogate' if not g else ''}", initial=drawn, scenario={"duration": 15.0},
             config={"initial": {"sd": {"p": sd, "v": 0.5}}, **({} if g else {"sensors": {"uwb": {"gate": None}}})},
             label=f"sd {sd:g} m{'' if g else ', no gate'}")
        for sd, g in ((1.0, True), (3.0, True), (10.0, True), (3.0, False), (10.0, False))] + [
        Case("init3_vector", initial=drawn, scenario={"duration": 15.0, "sensors": {"uwb": {"spacing_s": 0.001}}},
             config={"initial": {"sd": {"p": 3.0, "v": 0.5}}}, vector=True, label="sd 3 m, vector update")],
        ["rmse_init", "max_init", "rmse_all"]))
    out.append(Study("rate", "Range rate and process noise (route 1, optimal, first 30 s: the sharp corner)", [
        Case(f"rate{r:g}_S{S:g}", initial=drawn, scenario={**rate(r), "duration": 30.0},
             config={"process": {"spectral_density": S}},
             label=f"{r:g} cycles/s ({4 * r:g} ranges/s), S = {S:g}")
        for S in (0.2, 1.0) for r in (5.0, 1.0, 0.5, 0.25)],
        ["rmse_all", "rmse_steady", "rmse_man", "rmse_after", "nees_mean"]))
    out.append(Study("close", "Close passes (route 1, first 32 s, beacons d m beside its legs)", [
        Case(f"close{d:g}", beacons=close_beacons(d), initial=drawn, scenario={"duration": 32.0}, label=f"d = {d:g} m")
        for d in (0.25, 1.0, 3.0)] + [
        Case(f"close{d:g}_rate0.5", beacons=close_beacons(d), initial=drawn, scenario={**rate(0.5), "duration": 32.0},
             config={"process": {"spectral_density": 1.0}}, label=f"d = {d:g} m, 0.5 cycles/s, S = 1")
        for d in (0.25, 3.0)],
        ["rmse_all", "rmse_near", "rmse_steady", "nees_mean"]))
    out.append(Study("matched", "Truth drawn from the filters' own model (an honest covariance)", [
        Case(f"matched_{nm}_rate{r:g}", beacons=b, initial=drawn,
             matched={"duration": 20.0, "spectral_density": 1.0, "rate_hz": r},
             config={"process": {"spectral_density": 1.0}}, label=f"{nm} square, {r:g} cycles/s")
        for nm, b in (("30 x 20 m", OPTIMAL), ("6 x 6 m", SMALL)) for r in (5.0, 1.0, 0.25)],
        ["rmse_all", "rmse_steady", "nees_mean"]))
    out.append(Study("alpha", "UKF parameters (alpha; beta = 2, kappa = 0)", [
        Case(f"alpha{a:g}_{nm}", initial=drawn, scenario=sc, config={**cf, "filter": {"type": "ukf", "alpha": a}},
             label=f"alpha = {a:g}, {lab}")
        for nm, lab, sc, cf in (
            ("init10", "sd 10 m, no gate, 15 s", {"duration": 15.0},
             {"initial": {"sd": {"p": 10.0, "v": 0.5}}, "sensors": {"uwb": {"gate": None}}}),
            ("rate0.5", "0.5 cycles/s, S = 1, 30 s", {**rate(0.5), "duration": 30.0},
             {"process": {"spectral_density": 1.0}}))
        for a in (0.001, 1.0)],
        ["rmse_all", "rmse_init", "rmse_man"]))
    line_w = {"trajectory": {"waypoints": [[3.0, 3.0], [8.0, 0.5], [22.0, 0.5], [27.0, 3.0]]}}
    cross_w = {"trajectory": {"waypoints": [[3.0, 3.0], [27.0, -3.0]]}}
    out.append(Study("collinear", "Collinear beacons: the mirror image", [
        Case(f"line_init{sd:g}{'' if g else '_nogate'}", layout="line", initial=drawn,
             scenario={"duration": 30.0},
             config={"initial": {"sd": {"p": sd, "v": 0.5}}, **({} if g else {"sensors": {"uwb": {"gate": None}}})},
             label=f"route 1 (30 s), initial sd {sd:g} m{'' if g else ', no gate'}")
        for sd, g in ((1.0, True), (3.0, True), (10.0, True), (10.0, False))] + [
        Case("line_rate0.5", layout="line", initial=drawn, scenario={**rate(0.5), "duration": 30.0},
             config={"process": {"spectral_density": 1.0}}, label="route 1 (30 s), 2 ranges/s, S = 1"),
        Case("line_graze", layout="line", initial=drawn, scenario=line_w, label="walk 0.5 m from the line"),
        Case("line_cross", layout="line", initial=drawn, scenario=cross_w, label="walk across the line")],
        ["rmse_all", "max_all"]))
    return out


def _job(args):
    study_key, case, seed, keep_errors = args
    tmp = os.environ.get("UWB_TMP")
    return study_key, case.name, seed, run_pair(case, seed, tmpdir=tmp, keep_errors=keep_errors)


def run_all(all_studies: list[Study], n_seeds: int, jobs: int) -> tuple[dict, float]:
    """Run every (study, case, seed); returns {study: {case: [rows by seed]}} and the wall time (s)."""
    tasks = []
    for st in all_studies:
        for case in st.cases:
            for seed in range(st.seeds or n_seeds):
                tasks.append((st.key, case, seed, st.keep_errors))
    results: dict[str, dict[str, list]] = {st.key: {c.name: [] for c in st.cases} for st in all_studies}
    t0 = time.perf_counter()
    done, last = 0, 0.0
    print(f"{len(tasks)} runs of both filters ({sum(len(s.cases) for s in all_studies)} cases), {jobs} workers",
          flush=True)
    with tempfile.TemporaryDirectory(prefix="uwb_runs_") as tmp:
        os.environ["UWB_TMP"] = tmp
        with Pool(jobs) as pool:
            for key, name, seed, row in pool.imap_unordered(_job, tasks, chunksize=2):
                results[key][name].append(row)
                done += 1
                el = time.perf_counter() - t0
                if el - last > 10 or done == len(tasks):
                    last = el
                    eta = el / done * (len(tasks) - done)
                    print(f"  [{done:5d}/{len(tasks)}] {100 * done / len(tasks):5.1f}%  {el:6.0f} s elapsed, "
                          f"~{eta:4.0f} s to go  (last: {key}/{name} seed {seed})", flush=True)
    for per_case in results.values():
        for rows in per_case.values():
            rows.sort(key=lambda r: r["seed"])
    return results, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=50, help="seeds a case (default 50; the S sweep uses a fifth, >= 10)")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "uwb.md"), help="the results page")
    ap.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    ap.add_argument("--cache", metavar="PICKLE", help="(development) load the runs from this file if it exists, "
                    "else run and save them there; to rewrite the page without re-running")
    args = ap.parse_args(argv)
    from uwb_report import write_page

    out = Path(args.out)
    fig_dir = out.parent / out.stem
    fig_dir.mkdir(parents=True, exist_ok=True)
    all_studies = studies(max(10, args.seeds // 5))
    if args.cache and Path(args.cache).exists():
        with open(args.cache, "rb") as fh:
            results, wall = pickle.load(fh)
        print(f"runs loaded from {args.cache}")
    else:
        results, wall = run_all(all_studies, args.seeds, args.jobs)
        if args.cache:
            with open(args.cache, "wb") as fh:
                pickle.dump((results, wall), fh)
    figures = {}
    if not args.no_figures:
        from uwb_figures import make_figures
        print("figures ...", flush=True)
        labels = {(st.key, c.name): c.label or c.name for st in all_studies for c in st.cases}
        figures = make_figures(fig_dir, results, labels)
    summary = write_page(out, all_studies, results, figures, args.seeds, wall, args.jobs)
    (fig_dir / "summary.json").write_text(json.dumps(summary, indent=1, default=float) + "\n")
    print(f"wrote {out} and {fig_dir}/ ({wall:.0f} s of runs)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
