"""Peak memory of a run against its length: ``fusion run configs/abps_ins.yaml`` over a 10-minute and a
2-hour recording of the ABPS scenario, and a stdin soak.

    python benchmarks/bench_memory.py             # both lengths + the stdin soak (~2 min on 2 cores)
    python benchmarks/bench_memory.py --quick     # 2.5 and 10 minutes

The recordings are generated here (never committed): ``scenarios/abps_mine.yaml`` with its waypoint
route driven back and forth until the wanted duration (a U-turn at each end joins the laps), simulated by
``fusion simulate`` with seed 0. Each run is its own process (``fusion run ... --input LOG -q
--summary-json``); its peak resident set size comes from ``os.wait4`` (the kernel's ru_maxrss of that
child alone). The ratio long/short is the issue-9 target (the 2-hour run within 15% of the 10-minute
run). The soak pipes the long recording into ``fusion run --input -`` and samples the child's RSS
(``/proc/PID/status``) once a second: after the warm-up (the first quarter of the feed) it must stay flat
(issue 9: within 20 MB).

The result is printed and written to benchmarks/results/memory.md.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "scenarios" / "abps_mine.yaml"
CONFIG = ROOT / "configs" / "abps_ins.yaml"
OUT = ROOT / "benchmarks" / "results" / "memory.md"
LAP_S = 160.0  # about one lap of the route below (s)


def long_scenario(minutes: float, path: Path) -> Path:
    """The ABPS scenario driven back and forth for about ``minutes``; written to ``path``."""
    sc = yaml.safe_load(SCENARIO.read_text())
    wp = sc["trajectory"]["waypoints"]
    again = [{"at": wp[0], "radius": 0.25}] + wp[1:]
    back = [{"at": [19.0, 1.0, -0.40], "radius": 0.4}, {"at": [22.0, 0.5, -0.43], "radius": 0.4, "speed": 0.4},
            {"at": [22.0, 2.5, -0.43], "radius": 0.4}, {"at": [19.0, 2.2, -0.40], "speed": 1.0, "radius": 0.4},
            {"at": [5.0, 2.2, -0.31], "radius": 0.4}, {"at": [0.5, 2.5, -0.29], "radius": 0.4, "speed": 0.4},
            {"at": [0.5, 0.5, -0.29], "radius": 0.25}]
    laps = max(1, round(minutes * 60.0 / LAP_S))
    sc["trajectory"]["waypoints"] = wp + back + (again + back) * (laps - 1) + again
    sc["name"] = f"abps_long_{minutes:g}min"
    path.write_text(yaml.safe_dump(sc))
    return path


def simulate(minutes: float, tmp: Path) -> Path:
    log = tmp / f"abps_{minutes:g}min.log"
    sc = long_scenario(minutes, tmp / f"abps_{minutes:g}min.yaml")
    subprocess.run([sys.executable, "-m", "fusion.cli", "simulate", str(sc), "-o", str(log)], check=True,
                   stdout=subprocess.DEVNULL)
    return log


def peak_rss_run(log: Path, tmp: Path) -> dict:
    """Peak RSS (MB) and wall time of one ``fusion run`` process over ``log``."""
    summary = tmp / (log.stem + ".json")
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "fusion.cli", "run", str(CONFIG), "--input", str(log), "-q",
                             "--summary-json", str(summary)])
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if status != 0:
        raise SystemExit(f"fusion run failed on {log} (status {status})")
    s = json.loads(summary.read_text())
    return {"log": log.name, "data_s": s["duration_s"], "wall_s": wall, "peak_mb": usage.ru_maxrss / 1024.0,
            "rmse_m": s["errors"]["position_rmse_m"], "fixes": s["sensors"]["abps"]["used"]}


def _rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def soak(log: Path, rate_lines_s: float | None = None) -> dict:
    """Pipe ``log`` into ``fusion run --input -`` and sample the child's RSS once a second."""
    proc = subprocess.Popen([sys.executable, "-m", "fusion.cli", "run", str(CONFIG), "--input", "-", "-q"],
                            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL)
    samples: list[tuple[float, float]] = []
    t0 = time.perf_counter()

    def watch():
        while proc.poll() is None:
            r = _rss_mb(proc.pid)
            if r is not None:
                samples.append((time.perf_counter() - t0, r))
            time.sleep(1.0)

    th = threading.Thread(target=watch, daemon=True)
    th.start()
    with log.open("rb") as fh:
        for line in fh:
            proc.stdin.write(line)
    proc.stdin.close()
    end_feed = time.perf_counter() - t0
    proc.wait()
    done = time.perf_counter() - t0
    th.join(timeout=2)
    warm = [r for t, r in samples if t >= 0.25 * end_feed]
    return {"samples": len(samples), "feed_s": end_feed, "summary_after_s": done - end_feed,
            "rss_after_warmup_mb": warm[0] if warm else float("nan"), "rss_max_mb": max(warm) if warm else float("nan"),
            "growth_mb": (max(warm) - warm[0]) if warm else float("nan")}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2.5 and 10 minutes instead of 10 and 120")
    args = ap.parse_args(argv)
    short_min, long_min = (2.5, 10.0) if args.quick else (10.0, 120.0)
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        logs = {m: simulate(m, tmp) for m in (short_min, long_min)}
        rows = {m: peak_rss_run(logs[m], tmp) for m in logs}
        sk = soak(logs[long_min])
    ratio = rows[long_min]["peak_mb"] / rows[short_min]["peak_mb"]
    lines = ["# Peak memory against run length", "",
             "Regenerate: `python benchmarks/bench_memory.py` (recordings generated, not committed).", "",
             "| recording | data (s) | peak RSS (MB) | wall (s) | x real time | horizontal RMSE (m) |",
             "|---|---|---|---|---|---|"]
    for m, r in rows.items():
        lines.append(f"| {m:g} min ABPS route | {r['data_s']:.0f} | {r['peak_mb']:.1f} | {r['wall_s']:.1f} | "
                     f"{r['data_s'] / r['wall_s']:.0f} | {r['rmse_m']:.3f} |")
    lines += ["", f"Peak ratio {long_min:g} min / {short_min:g} min: **{ratio:.3f}** (target: at most 1.15).", "",
              f"Stdin soak (`fusion run configs/abps_ins.yaml --input -` fed the {long_min:g} min recording as fast as "
              f"it reads, {sk['feed_s']:.0f} s): RSS {sk['rss_after_warmup_mb']:.1f} MB after the warm-up, "
              f"{sk['rss_max_mb']:.1f} MB at most, growth **{sk['growth_mb']:.1f} MB** (target: within 20 MB); "
              f"the summary came {sk['summary_after_s']:.2f} s after the input ended.", ""]
    text = "\n".join(lines)
    print(text)
    if not args.quick:
        OUT.parent.mkdir(parents=True, exist_ok=True)
        OUT.write_text(text)
    return 0 if ratio <= 1.15 and sk["growth_mb"] <= 20.0 else 1


if __name__ == "__main__":
    sys.exit(main())
