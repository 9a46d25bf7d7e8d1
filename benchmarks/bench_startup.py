"""Start-up cost of the ``fusion`` command, as a ratio to ``python -c "import numpy"`` measured in the
same run, and the real-time factor of the whole headline process.

    python benchmarks/bench_startup.py            # best of 7 runs each, writes benchmarks/results/startup.md
    python benchmarks/bench_startup.py --repeats 3

Measured as processes (what a user waits for), each the best wall time of ``--repeats`` runs:

- ``python -c "import numpy"``: the reference;
- ``fusion --help``: target within 2x the reference (issue 9);
- ``fusion validate configs/abps_ins.yaml``;
- ``fusion run configs/abps_ins.yaml -q``: the headline command, whole process; its real-time factor is
  the recording's duration over the process's wall time (target at least 150x);
- the replay alone (``fusion.pipeline.run`` in a warm process, best of the repeats; target at least 250x).

Each command runs with the environment the CLI sets for itself (single-threaded BLAS) so that the
reference and the commands are alike, and with bytecode caches as an installed package has them (one
untimed run first writes them; PYTHONDONTWRITEBYTECODE is dropped for the children).
"""
from __future__ import annotations

import os

# The replay alone runs in this process: BLAS single-threaded, as fusion/cli.py sets it for `fusion run`
# (before numpy is first imported).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "abps_ins.yaml"
OUT = ROOT / "benchmarks" / "results" / "startup.md"
FUSION = [sys.executable, "-m", "fusion.cli"]


def best_wall(cmd: list[str], repeats: int) -> tuple[float, float]:
    """(best wall s, best CPU s = user + system of the child) over ``repeats`` runs. CPU time is the
    steadier figure on a shared machine (another job's load lengthens the wall time, not the CPU time)."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    # As installed: pip compiles every module to bytecode at install time, so a user's process loads
    # .pyc files. A sandbox's PYTHONDONTWRITEBYTECODE would make every run compile ~90 modules from
    # source (~10% of the headline process), which no installed copy does: it is dropped, and one run
    # before the timed ones writes the caches.
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT, env=env, check=False)
    best, best_cpu = float("inf"), float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        if status != 0:
            raise SystemExit(f"{' '.join(cmd)} failed (status {status})")
        best = min(best, time.perf_counter() - t0)
        best_cpu = min(best_cpu, usage.ru_utime + usage.ru_stime)
    return best, best_cpu


def replay_alone(repeats: int) -> tuple[float, float, float]:
    """(best wall s and best CPU s of the replay in this process, the recording's duration s)."""
    from fusion import pipeline
    from fusion.config import load_system

    best, best_cpu, duration = float("inf"), float("inf"), 0.0
    for _ in range(repeats):
        system = load_system(CONFIG)
        t0, c0 = time.perf_counter(), time.process_time()
        result = pipeline.run(system, system.recording)
        best = min(best, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
        meta = result.parsed.header.meta
        duration = float(meta["duration"]) if "duration" in meta else result.summary["duration_s"]
    return best, best_cpu, duration


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args(argv)
    r = args.repeats
    numpy_s, numpy_c = best_wall([sys.executable, "-c", "import numpy"], r)
    help_s, help_c = best_wall([*FUSION, "--help"], r)
    validate_s, validate_c = best_wall([*FUSION, "validate", str(CONFIG)], r)
    run_s, run_c = best_wall([*FUSION, "run", str(CONFIG), "-q"], r)
    replay_s, replay_c, duration = replay_alone(r)
    load = os.getloadavg()[0]
    rows = [("python -c \"import numpy\"", numpy_s, numpy_c, "reference"),
            ("fusion --help", help_s, help_c, "at most 2.0x the reference"),
            ("fusion validate configs/abps_ins.yaml", validate_s, validate_c, ""),
            ("fusion run configs/abps_ins.yaml -q (whole process)", run_s, run_c, "")]
    lines = ["# Start-up and the headline process", "",
             "Regenerate: `python benchmarks/bench_startup.py` (best of "
             f"{r} runs each after one untimed run, with bytecode caches as installed; load average {load:.1f} on {os.cpu_count()} cores when measured: on a busy machine "
             "the CPU columns are the steadier ones).", "",
             "| command | wall (s) | wall ratio to numpy import | CPU (s) | CPU ratio | target |",
             "|---|---|---|---|---|---|"]
    for name, s, c, target in rows:
        lines.append(f"| `{name}` | {s:.3f} | {s / numpy_s:.2f} | {c:.3f} | {c / numpy_c:.2f} | {target} |")
    lines += ["", f"Recording: {duration:.1f} s of data (`recordings/abps_mine.log`).", "",
              f"- whole `fusion run configs/abps_ins.yaml` process: **{duration / run_s:.0f}x** real time by wall "
              f"time, {duration / run_c:.0f}x by CPU time (target at least 150x)",
              f"- the replay alone (`fusion.pipeline.run`, warm process): **{duration / replay_s:.0f}x** by wall "
              f"time, {duration / replay_c:.0f}x by CPU time (target at least 250x)",
              f"- start-up and summary: {run_s - replay_s:.3f} s of the {run_s:.3f} s (wall)", ""]
    text = "\n".join(lines)
    print(text)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
