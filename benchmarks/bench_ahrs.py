"""AHRS (configs/ahrs.yaml, issue 32 item 4): the whole ``fusion run`` process as a multiple of real time at
the IMU's native 100 Hz, and the cost of one attitude update against one ``ins`` predict.

    python benchmarks/bench_ahrs.py                 # ~30 s; prints the table, writes benchmarks/results/ahrs.md
    python benchmarks/bench_ahrs.py --repeats 5

Whole process: ``python -m fusion.cli run configs/ahrs.yaml -q`` as a subprocess (start-up, imports, parsing,
the filter); the recording's duration divided by its CPU time (user + sys of the child) and by its wall
time, best of ``--repeats``. The machine is shared: CPU time is the figure other load disturbs least.

Per step (in this process, best of rounds of 2,000 calls, interleaved): the EKF's predict of the 16-state
``ins`` (one IMU sample), its ``gravity`` and ``magnetometer_checked`` updates of the 7-state
``gyro_attitude`` AHRS, and the AHRS predict of one sample; the ratio update / INS predict must stay <= 1.
No assertion here: a benchmark reports, the tests do not time anything.
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "ahrs.yaml"
OUT = ROOT / "benchmarks" / "results" / "ahrs.md"


def recording_duration() -> float:
    """Seconds of data in the config's recording (its ``# duration`` header line)."""
    log = ROOT / "recordings" / "ahrs_handheld.log"
    for line in log.open():
        if line.startswith("# duration:"):
            return float(line.split(":")[1])
    raise SystemExit(f"{log}: no '# duration' line")


def whole_process(repeats: int) -> tuple[float, float]:
    """(best CPU s, best wall s) of ``fusion run configs/ahrs.yaml -q`` as a subprocess."""
    best_cpu = best_wall = float("inf")
    for _ in range(repeats):
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        w0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "fusion.cli", "run", str(CONFIG), "-q"], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wall = time.perf_counter() - w0
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        best_cpu = min(best_cpu, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime))
        best_wall = min(best_wall, wall)
    return best_cpu, best_wall


def per_step(rounds: int = 15, calls: int = 2000) -> dict[str, float]:
    """Microseconds per call (best round) of the steps compared (module docstring)."""
    from fusion import testing
    from fusion.api import Belief, Message, StateLayout

    ekf = testing.build("filter", "ekf")
    ins = testing.registry_class("process", "ins")()
    ahrs_layout = StateLayout.parse("q:4:quaternion bw:3")
    ahrs = testing.registry_class("process", "gyro_attitude")()
    from fusion.api import BuildContext

    ctx = BuildContext(layout=ahrs_layout, sensor="acc")
    grav = testing.registry_class("measurement", "gravity")(None, ctx)
    mag_cls = testing.registry_class("measurement", "magnetometer_checked")
    mag = mag_cls(mag_cls.Params(field_ned=(21.0, 1.6, 44.0)), BuildContext(layout=ahrs_layout, sensor="mag"))
    q = np.array([0.9, 0.1, -0.2, 0.3]) / np.linalg.norm([0.9, 0.1, -0.2, 0.3])
    x_ins = np.zeros(16)
    x_ins[6:10] = q
    b_ins = Belief(0.0, x_ins, P=np.eye(16) * 1e-3)
    b_ahrs = Belief(0.0, np.concatenate([q, np.zeros(3)]), P=np.eye(7) * 1e-4)
    u = np.array([0.3, -0.2, -9.7, 0.1, -0.05, 0.2])
    o_g = grav.observe(Message(1.0, "acc", (0.3, -0.2, -9.7)))
    z_m = mag.h(b_ahrs.x) + 0.1
    o_m = mag.observe(Message(1.0, "mag", tuple(z_m.tolist())))
    R_m = np.eye(3) * 0.09
    cases = {
        "ins predict (16 states, one sample)": lambda: ekf.predict(b_ins, ins, u, 0.01),
        "gravity update (AHRS, 7 states)": lambda: ekf.update(b_ahrs, o_g.model, o_g.z, o_g.R),
        "magnetometer_checked update (AHRS)": lambda: ekf.update(b_ahrs, o_m.model, o_m.z, R_m),
        "gyro_attitude predict (one sample)": lambda: ekf.predict(b_ahrs, ahrs, u, 0.01),
    }
    best = {k: float("inf") for k in cases}
    for _ in range(rounds):
        for name, fn in cases.items():
            t0 = time.perf_counter()
            for _ in range(calls):
                fn()
            best[name] = min(best[name], (time.perf_counter() - t0) / calls * 1e6)
    return best


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-write", action="store_true", help="print only")
    args = ap.parse_args(argv)
    duration = recording_duration()
    cpu, wall = whole_process(args.repeats)
    steps = per_step()
    ins = steps["ins predict (16 states, one sample)"]
    lines = ["# AHRS speed (configs/ahrs.yaml)", "",
             "Regenerate: `python benchmarks/bench_ahrs.py` (2-core VM shared with other jobs; rerun for your "
             "machine).",
             "", f"Whole process, recordings/ahrs_handheld.log ({duration:g} s, IMU 100 Hz, accelerometer and "
             "magnetometer updates 25 Hz each), best of " f"{args.repeats}:", "",
             "| measure | seconds | x real time |", "|---|---|---|",
             f"| CPU (user + sys) | {cpu:.2f} | {duration / cpu:.0f} |",
             f"| wall | {wall:.2f} | {duration / wall:.0f} |", "",
             "Per step (EKF, best of 15 rounds of 2,000 calls):", "",
             "| step | us | / ins predict |", "|---|---|---|"]
    lines += [f"| {k} | {v:.1f} | {v / ins:.2f} |" for k, v in steps.items()]
    text = "\n".join(lines) + "\n"
    print(text)
    if not args.no_write:
        OUT.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
