"""Paper 002 system (configs/imu_gps_mag_ekf.yaml): the whole ``fusion run`` process as a multiple of real
time, per filter, and the replay alone (no interpreter start-up).

    python benchmarks/bench_imu_gps_mag.py              # ~1 min
    python benchmarks/bench_imu_gps_mag.py --repeats 5
    python benchmarks/bench_imu_gps_mag.py --instructions   # + instruction counts (valgrind), ~4 min
    python benchmarks/bench_imu_gps_mag.py --pure --filters ekf   # the numpy code, not the compiled kernels

The process is timed as a subprocess (``fusion run CONFIG -q``: Python start-up, imports, parsing, the
filter); its CPU time (user + sys of the child, best of ``--repeats``) and wall time are divided into the
recording's duration (309 s of data). The replay alone is fusion.pipeline.run in this process.

``--instructions`` adds the instructions the whole process executes (valgrind's callgrind, "Collected"),
a measure that other load on the machine does not disturb (times on a shared VM vary by 15% and more):
compare two versions by it, and by times measured in the same session.

``--pure`` sets ``FUSION_PURE_PYTHON=1`` (fusion/kernels.py) for the runs: the plugins' numpy code instead of
their compiled kernels (setup.py KERNELS), the "before" of a kernel, measured in the same session.
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import re  # noqa: E402
import resource  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "imu_gps_mag_ekf.yaml"
DURATION = 309.438           # s: recordings/car_gps_mag.log header


def process_time(args: list[str], repeats: int) -> tuple[float, float]:
    best_cpu = best_wall = float("inf")
    for _ in range(repeats):
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        w0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "fusion.cli", "run", str(CONFIG), "-q", *args], check=True)
        wall = time.perf_counter() - w0
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
        best_cpu, best_wall = min(best_cpu, cpu), min(best_wall, wall)
    return best_cpu, best_wall


def process_instructions(args: list[str]) -> float | None:
    """Instructions (G) of one ``fusion run CONFIG -q`` process under callgrind, or None without valgrind."""
    if shutil.which("valgrind") is None:
        return None
    out = subprocess.run(["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null", sys.executable, "-m",
                          "fusion.cli", "run", str(CONFIG), "-q", *args], capture_output=True, text=True, check=True)
    m = re.search(r"Collected\s*:\s*(\d+)", out.stderr)
    return int(m.group(1)) / 1e9 if m else None


def replay_time(filter_args: dict | None, repeats: int) -> float:
    from fusion import pipeline
    from fusion.config import load_system
    best = float("inf")
    for _ in range(repeats):
        system = load_system(CONFIG, filter_override=filter_args)
        c0 = time.process_time()
        pipeline.run(system, system.recording)
        best = min(best, time.process_time() - c0)
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--instructions", action="store_true", help="also count the process's instructions (valgrind)")
    ap.add_argument("--pure", action="store_true", help="FUSION_PURE_PYTHON=1: the numpy code, not the C kernels")
    ap.add_argument("--filters", default="ekf,ukf,srukf", help="comma-separated subset of ekf,ukf,srukf")
    args = ap.parse_args(argv)
    if args.pure:
        os.environ["FUSION_PURE_PYTHON"] = "1"          # the children inherit it; this process imports later
    chosen = set(args.filters.split(","))
    extra_head = " process instructions (G) |" if args.instructions else ""
    print("| filter | process CPU s | x real time (CPU) | process wall s | replay CPU s | replay x real time |"
          + extra_head)
    print("|---|---:|---:|---:|---:|---:|" + ("---:|" if args.instructions else ""))
    for name, extra, spec in (("ekf", [], None), ("ukf", ["--filter", "ukf", "--filter-param", "alpha=0.5"],
                                                  {"type": "ukf", "alpha": 0.5}),
                              ("srukf", ["--filter", "srukf", "--filter-param", "alpha=0.5"],
                               {"type": "srukf", "alpha": 0.5})):
        if name not in chosen:
            continue
        cpu, wall = process_time(extra, args.repeats)
        rep = replay_time(spec, args.repeats)
        ir = ""
        if args.instructions:
            g = process_instructions(extra)
            ir = f" {g:.2f} |" if g is not None else " - |"
        print(f"| {name} | {cpu:.2f} | {DURATION / cpu:.0f}x | {wall:.2f} | {rep:.2f} | {DURATION / rep:.0f}x |{ir}",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
