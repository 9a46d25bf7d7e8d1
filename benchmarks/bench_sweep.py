"""fusion sweep: where a trial's time goes, and the paper-001 UKF-against-EKF study through the sweep
against the hand-rolled path it replaces (experiments/uwb_cases.run_pair), measured in the same run.

    python benchmarks/bench_sweep.py                  # 8 seeds of the four cases (~2-3 min)
    python benchmarks/bench_sweep.py --seeds 50       # the page's 50 seeds (long)

1. Per trial of the batched engine (configs/uwb_pv_ukf.yaml on scenarios/uwb_route1.yaml, 68 s, 1357
   ranges), at 8 seeds and at the --seeds given: wiring, the recordings (simulated and read as arrays,
   fusion.sweep.lockstep), the filter math, the statistics (fusion.sweep.batchstats: truth
   interpolation, errors, NEES, NIS); "overhead" is everything but the filter math.
2. The four cases of docs/results/uwb.md (routes 1, 2 x optimal, collinear beacons), UKF and EKF, the
   same seeds: the old path (one simulation per seed, both filters through fusion.pipeline.run, its own
   errors and NEES), then ``fusion.sweep.sweep`` with the default engine (batched), both on one core; the
   ratio is per trial pair.
"""
from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "experiments"))

CASES = [("route1", "optimal"), ("route1", "line"), ("route2", "optimal"), ("route2", "line")]


def per_trial(seeds: int) -> dict[str, float]:
    from fusion.sweep.batched import run_batch
    from fusion.sweep.grid import trials_of

    ts = trials_of(str(ROOT / "configs/uwb_pv_ukf.yaml"), str(ROOT / "scenarios/uwb_route1.yaml"), range(seeds),
                   ["ukf"], [])
    run_batch(ts[:2])                                    # imports, caches
    tm: dict[str, float] = {}
    t0 = time.perf_counter()
    run_batch(ts, tm)
    tm["total"] = time.perf_counter() - t0
    return {k: 1e3 * v / seeds for k, v in tm.items()}


def old_path(seeds: int) -> tuple[float, float]:
    """(wall, CPU) seconds for the four cases x seeds through experiments/uwb_cases.run_pair (both filters)."""
    from uwb_cases import Case, run_pair

    t0, c0 = time.perf_counter(), time.process_time()
    for r, lay in CASES:
        case = Case(f"{r}_{lay}", r, lay)
        for s in range(seeds):
            run_pair(case, s)
    return time.perf_counter() - t0, time.process_time() - c0


def new_path(seeds: int) -> tuple[float, float]:
    from fusion.sweep.grid import sweep, trials_of
    from uwb_cases import CONFIG, SCENARIO

    ts = []
    for r, lay in CASES:
        ts += trials_of(str(ROOT / CONFIG[lay]), str(ROOT / SCENARIO[r, lay]), range(seeds), ["ukf", "ekf"], [])
    with tempfile.TemporaryDirectory() as d:
        t0, c0 = time.perf_counter(), time.process_time()
        sweep(ts, Path(d) / "r.csv", engine="batch")
        return time.perf_counter() - t0, time.process_time() - c0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=8)
    args = ap.parse_args(argv)
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores\n")
    for i, n in enumerate(sorted({8, max(args.seeds, 8)})):
        tm = per_trial(n)
        if i == 0:
            print("| per trial (batched engine, ms) | seeds | " + " | ".join(tm) + " | overhead (all but filter math) |")
            print("|---|---:|" + "---:|" * (len(tm) + 1))
        print(f"| route 1, ukf | {n} | " + " | ".join(f"{v:.1f}" for v in tm.values()) +
              f" | {tm['total'] - tm['filter_math']:.1f} |", flush=True)
    print()
    (new, new_c), (old, old_c) = new_path(args.seeds), old_path(args.seeds)
    n = len(CASES) * args.seeds
    print(f"four cases x {args.seeds} seeds x (ukf, ekf): old path {old:.1f} s wall, {old_c:.1f} s CPU "
          f"({1e3 * old / n:.0f} ms a seed), fusion sweep {new:.1f} s wall, {new_c:.1f} s CPU "
          f"({1e3 * new / n:.0f} ms a seed): {old / new:.1f}x wall, {old_c / new_c:.1f}x CPU")
    return 0


if __name__ == "__main__":
    sys.exit(main())
