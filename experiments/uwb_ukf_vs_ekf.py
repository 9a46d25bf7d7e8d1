#!/usr/bin/env python3
"""Paper 001, UKF against EKF over many seeds, through ``fusion sweep``: regenerates docs/results/uwb.md.

    python experiments/uwb_ukf_vs_ekf.py                  # 50 seeds for the paper's cases, 20 for the others
    python experiments/uwb_ukf_vs_ekf.py --seeds 12       # a quick look (the page says how many seeds)
    python experiments/uwb_ukf_vs_ekf.py --work /tmp/uwb  # keep the results files there (resumable)

Every study is a ``fusion.sweep`` grid over the shipped configs (configs/uwb_pv_ukf*.yaml) and scenarios
(scenarios/uwb_route*.yaml) with ``--param`` overrides; a trial simulates the scenario with its seed and runs
it through the pipeline (batched over the seeds where the system allows), so UKF and EKF see the same
ranges and pair by seed. No simulator, truth interpolation or NEES of its own: the rows are those of
``fusion sweep`` (the run summary's errors and consistency). The page is written by
experiments/uwb_sweep_page.py.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

CONFIG = {"optimal": "configs/uwb_pv_ukf.yaml", "line": "configs/uwb_pv_ukf_line.yaml"}
SCENARIO = {("route1", "optimal"): "scenarios/uwb_route1.yaml", ("route1", "line"): "scenarios/uwb_route1_line.yaml",
            ("route2", "optimal"): "scenarios/uwb_route2.yaml", ("route2", "line"): "scenarios/uwb_route2_line.yaml"}
LABEL = {"optimal": "beacons around", "line": "collinear"}


@dataclass
class Study:
    """One grid: cases (route, layout), its params, the seeds, with the smoother or not."""

    key: str
    title: str
    cases: list[tuple[str, str]]
    params: list[tuple[str, list[str]]] = field(default_factory=list)
    seeds: int = 50
    smooth: bool = False
    note: str = ""
    initial: str = "drawn"   # every study draws each seed's initial mean from N(true start, P0) (Monte Carlo)


def studies(n: int, n_tune: int) -> list[Study]:
    """The page's studies (what each varies; the rest is the shipped config and scenario)."""
    four = [(r, lay) for r in ("route1", "route2") for lay in ("optimal", "line")]
    init = [("scenario.duration", ["15.0"]), ("initial.sd.p", ["10.0"])]
    return [
        Study("cases", "The four cases of the paper (as shipped)", four, seeds=n),
        Study("smoothed", "Filtered against smoothed (RTS, fusion/smoothing; issue 17)", four, seeds=n, smooth=True),
        Study("process_noise", "Process noise S (tuning; both filters the same S)", [("route1", "optimal"),
              ("route2", "optimal")], [("process.spectral_density", ["0.05", "0.1", "0.2", "0.5", "1.0"])],
              seeds=n_tune),
        Study("initial", "A wide initial belief: sd 10 m, each seed's mean drawn from it, first 15 s",
              [("route1", "optimal")], init + [("sensors.uwb.gate", ["{type: chi2, probability: 0.9999}", "null"])],
              seeds=n),
        Study("rate", "Range rate and process noise (route 1, beacons around, first 30 s: the sharp corner)",
              [("route1", "optimal")], [("scenario.duration", ["30.0"]),
                                        ("scenario.sensors.uwb.rate_hz", ["5.0", "1.0", "0.5"]),
                                        ("process.spectral_density", ["0.2", "1.0"])], seeds=n_tune),
        Study("collinear_initial", "Collinear beacons from a wide initial belief (sd 10 m; route 1, first 30 s)",
              [("route1", "line")], [("scenario.duration", ["30.0"]), ("initial.sd.p", ["10.0"])], seeds=n),
    ]


def run_study(st: Study, work: Path, jobs: int) -> list[dict]:
    """The study's rows: one fusion.sweep per case (resumable in ``work``)."""
    from fusion.sweep.grid import sweep, trials_of

    rows = []
    for route, lay in st.cases:
        trials = trials_of(CONFIG[lay], SCENARIO[route, lay], range(st.seeds), ["ukf", "ekf"], st.params, st.smooth,
                           st.initial)
        got, info = sweep(trials, work / f"{st.key}_{route}_{lay}.csv", jobs=jobs)
        for r in got:
            r["case"] = f"{route.replace('route', 'route ')}, {LABEL[lay]}"
        rows += got
        print(f"  {st.key} {route} {lay}: {len(got)} rows ({info['skipped']} resumed; {info['engines']})", flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=50, help="seeds of the main studies (default 50)")
    ap.add_argument("--tune-seeds", type=int, default=20, help="seeds of the tuning grids (default 20)")
    ap.add_argument("--jobs", type=int, default=2, help="pool workers for what is not batched (default 2)")
    ap.add_argument("--work", help="folder for the results files (default: a temporary one)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "uwb.md"), help="the results page")
    args = ap.parse_args(argv)
    from uwb_sweep_page import write_page

    tmp = None
    if args.work:
        work = Path(args.work)
        work.mkdir(parents=True, exist_ok=True)
    else:
        tmp = tempfile.TemporaryDirectory(prefix="uwb_sweep_")
        work = Path(tmp.name)
    t0 = time.perf_counter()
    results, walls = {}, {}
    for st in studies(args.seeds, args.tune_seeds):
        t1 = time.perf_counter()
        results[st.key] = run_study(st, work, args.jobs)
        walls[st.key] = time.perf_counter() - t1
    wall = time.perf_counter() - t0
    out = Path(args.out)
    write_page(out, studies(args.seeds, args.tune_seeds), results, walls, wall, args)
    print(f"wrote {out} ({wall:.0f} s of sweeps)")
    if tmp is not None:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
