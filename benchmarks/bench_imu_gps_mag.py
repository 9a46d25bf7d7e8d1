"""Paper 002 system (configs/imu_gps_mag_ekf.yaml): the whole ``fusion run`` process as a multiple of real
time, per filter, and the replay alone (no interpreter start-up).

    python benchmarks/bench_imu_gps_mag.py              # ~2 min; writes benchmarks/results/imu_gps_mag.md
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


OUT = ROOT / "benchmarks" / "results" / "imu_gps_mag.md"
TARGET = 300.0               # x real time, the whole process (issue 12)


def _table(rows: list[tuple[str, float, float, float | None, float | None]], instructions: bool) -> list[str]:
    head = "| run | process CPU s | x real time (CPU) | process wall s | x real time (wall) | replay CPU s | replay x real time |"
    lines = [head + (" process instructions (G) |" if instructions else ""),
             "|---|---:|---:|---:|---:|---:|---:|" + ("---:|" if instructions else "")]
    for name, cpu, wall, rep, g in rows:
        r = f" {rep:.2f} | {DURATION / rep:.0f}x |" if rep is not None else " - | - |"
        ir = (f" {g:.2f} |" if g is not None else " - |") if instructions else ""
        lines.append(f"| {name} | {cpu:.2f} | {DURATION / cpu:.0f}x | {wall:.2f} | {DURATION / wall:.0f}x |{r}{ir}")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--instructions", action="store_true", help="also count the process's instructions (valgrind)")
    ap.add_argument("--pure", action="store_true", help="FUSION_PURE_PYTHON=1 for every row: the numpy code only")
    ap.add_argument("--filters", default="ekf,ukf,srukf", help="comma-separated subset of ekf,ukf,srukf")
    ap.add_argument("--out", type=Path, default=OUT, help=f"the page to write (default {OUT.relative_to(ROOT)}; '-': none)")
    args = ap.parse_args(argv)
    # a user's processes keep their bytecode caches: without them every child recompiles ~80 modules
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    if args.pure:
        os.environ["FUSION_PURE_PYTHON"] = "1"          # the children inherit it; this process imports later
    chosen = set(args.filters.split(","))
    runs = [("ekf", [], None), ("ukf", ["--filter", "ukf", "--filter-param", "alpha=0.5"], {"type": "ukf", "alpha": 0.5}),
            ("srukf", ["--filter", "srukf", "--filter-param", "alpha=0.5"], {"type": "srukf", "alpha": 0.5})]
    subprocess.run([sys.executable, "-m", "fusion.cli", "run", str(CONFIG), "-q"], check=True)   # warm caches, untimed
    rows = []
    for name, extra, spec in runs:
        if name not in chosen:
            continue
        cpu, wall = process_time(extra, args.repeats)
        rep = replay_time(spec, args.repeats)
        g = process_instructions(extra) if args.instructions else None
        rows.append((name + (" (numpy code)" if args.pure else ""), cpu, wall, rep, g))
        print(_table(rows[-1:], args.instructions)[-1], flush=True)
        if name == "ekf" and not args.pure:
            # the same process on the numpy code (FUSION_PURE_PYTHON=1), in the same session: what the kernels buy
            os.environ["FUSION_PURE_PYTHON"] = "1"
            try:
                cpu_p, wall_p = process_time(extra, args.repeats)
                g_p = process_instructions(extra) if args.instructions else None
            finally:
                del os.environ["FUSION_PURE_PYTHON"]
            rows.append(("ekf, numpy code (FUSION_PURE_PYTHON=1)", cpu_p, wall_p, None, g_p))
            print(_table(rows[-1:], args.instructions)[-1], flush=True)
    if str(args.out) == "-" or not rows:
        return 0
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    ekf = rows[0]
    text = "\n".join([
        "# Paper 002 system: the whole process against real time",
        "",
        f"Regenerate: `python benchmarks/bench_imu_gps_mag.py{' --instructions' if args.instructions else ''}` "
        f"(best of {args.repeats} runs each after one untimed run; load average {load:.1f} on "
        f"{os.cpu_count()} cores when measured: on a busy machine the CPU columns are the steadier ones).",
        "",
        f"`fusion run configs/imu_gps_mag_ekf.yaml -q` as a subprocess (interpreter start-up, imports, parsing the "
        f"33k lines, the 22-state EKF at 50 Hz, GPS and magnetometer updates, errors against truth, the summary) "
        f"over {DURATION:.1f} s of data (recordings/car_gps_mag.log); the replay alone is `fusion.pipeline.run` "
        "in this process. UKF and SR-UKF rows: the same config with `--filter`.",
        "",
        *_table(rows, args.instructions),
        "",
        f"- whole `fusion run configs/imu_gps_mag_ekf.yaml` process ({ekf[0]}): **{DURATION / ekf[2]:.0f}x** real time "
        f"by wall time, {DURATION / ekf[1]:.0f}x by CPU time (target at least {TARGET:.0f}x, issue 12)",
        "",
        "The compiled kernels (setup.py KERNELS: the INS run, the Kalman chain and update, the magnetometer) are "
        "described in benchmarks/README.md, \"Paper 002 system\"; the numpy row is the same code with them off.",
        ""])
    args.out.write_text(text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
