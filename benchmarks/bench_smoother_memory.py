"""Peak memory of a smoothed run against its length: ``fusion run configs/abps_ins.yaml --smooth`` over a
10-minute and a 2-hour recording of the ABPS route (the recordings of benchmarks/bench_memory.py).

    python benchmarks/bench_smoother_memory.py            # ~4 min on 2 cores
    python benchmarks/bench_smoother_memory.py --quick    # 2.5 and 10 minutes

Each run is its own process; its peak resident set size comes from ``os.wait4`` (ru_maxrss of that child
alone), the bytes the smoother wrote to its temporary store from the summary (``smoothed.store``). The
forward records go to disk past each store's in-memory budget (1 MiB, fusion/smoothing/store.py), so the
peak should stay flat (issue 17: within the pipeline's flat-memory bound plus the store on disk).
Written to benchmarks/results/smoother_memory.md.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_memory import CONFIG, simulate  # noqa: E402

OUT = ROOT / "benchmarks" / "results" / "smoother_memory.md"


def run(log: Path, tmp: Path, smooth: bool) -> dict:
    summary = tmp / (log.stem + ("_s" if smooth else "") + ".json")
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "fusion.cli", "run", str(CONFIG), "--input", str(log), "-q",
                             "--summary-json", str(summary), *(["--smooth"] if smooth else [])])
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if status != 0:
        raise SystemExit(f"fusion run failed on {log} (status {status})")
    s = json.loads(summary.read_text())
    sm = s.get("smoothed", {})
    return {"data_s": s["duration_s"], "wall_s": wall, "peak_mb": usage.ru_maxrss / 1024.0,
            "rmse": s["errors"]["position_rmse_m"], "rmse_s": sm.get("errors", {}).get("position_rmse_m"),
            "disk_mb": sm.get("store", {}).get("bytes_on_disk", 0) / 1e6, "nodes": sm.get("nodes"),
            "backward_s": sm.get("backward_wall_s")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    short_min, long_min = (2.5, 10.0) if args.quick else (10.0, 120.0)
    rows = []
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        for m in (short_min, long_min):
            log = simulate(m, tmp)
            for smooth in (False, True):
                r = run(log, tmp, smooth)
                rows.append((m, smooth, r))
                print(m, smooth, r, flush=True)
    lines = ["# Peak memory of a smoothed run against its length", "",
             "Regenerate: `python benchmarks/bench_smoother_memory.py` (recordings generated as in "
             "benchmarks/bench_memory.py, not committed).", "",
             "| recording | run | data (s) | peak RSS (MB) | wall (s) | store on disk (MB) | nodes | backward (s) | "
             "horizontal RMSE filtered / smoothed (m) |", "|---|---|---:|---:|---:|---:|---:|---:|---|"]
    for m, smooth, r in rows:
        rm = f"{r['rmse']:.3f} / {r['rmse_s']:.3f}" if smooth else f"{r['rmse']:.3f}"
        lines.append(f"| {m:g} min ABPS route | {'--smooth' if smooth else 'plain'} | {r['data_s']:.0f} | "
                     f"{r['peak_mb']:.1f} | {r['wall_s']:.1f} | {r['disk_mb']:.1f} | {r['nodes'] or '-'} | "
                     f"{r['backward_s'] if r['backward_s'] is None else round(r['backward_s'], 1)} | {rm} |")
    lines += ["", "Wall times are of single runs on a shared 2-core machine (other jobs were running); the careful "
              "timing of the two passes is benchmarks/results/smoother.md (`python benchmarks/bench_smoother.py`). "
              "The peak is bounded by the stores' in-memory budgets (1 MiB each, four stores, plus a chunk buffer "
              "of at most 256 KiB each, fusion/smoothing/store.py), not by the length: a run of a few minutes already "
              "fills them and spills. (With 8 MB budgets and 1024-record chunks, up to 8.9 MB a buffer, the ratio was "
              "1.181: the budgets were still filling at 10 minutes.)"]
    peak = {(m, s): r["peak_mb"] for m, s, r in rows}
    lines += ["", f"Smoothed peak ratio {long_min:g} min / {short_min:g} min: "
              f"**{peak[(long_min, True)] / peak[(short_min, True)]:.3f}**; smoothed / plain at {long_min:g} min: "
              f"**{peak[(long_min, True)] / peak[(long_min, False)]:.3f}**.", ""]
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
