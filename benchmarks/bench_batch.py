"""Batched filters (fusion.batch) against a loop of single filters, measured in the same run.

    python benchmarks/bench_batch.py                    # the table (~1-2 min)
    python benchmarks/bench_batch.py --n 1000,4000 --steps 200 --rounds 3

Rates are filter-steps per second: N filters x steps / the best round's wall time. A step of the
4-state UWB model (configs/uwb_pv_ukf.yaml: pv + one range, the shipped gate) is one predict (dt =
0.05 s) and one range update, each filter with its own ranges. A step of the 16-state INS (``ins``,
trapezoidal) is one IMU predict (dt = 0.01 s, each filter its own sample) with a 3-range update every
10th step. The reference is the in-process loop of N single filters (plugins/filters/) on the same
inputs, on a subset of the filters (its rate does not depend on N). The batch equals those single
filters to 1e-12 (tests/batch/).
"""
from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")      # tiny matrices: BLAS threads only add latency (as fusion/cli.py)

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


CPU = [np.inf]   # best round's process CPU time of the last batch benchmark (s)


def uwb_setup():
    from fusion.api import Message
    from fusion.config import load_system

    s = load_system(ROOT / "configs" / "uwb_pv_ukf.yaml")
    models = [s.sensors["uwb"].model.observe(Message(0.0, "uwb", (b, 1.0), 0)).model for b in s.beacons]
    return s, models


def bench_uwb(name: str, N: int, steps: int, rounds: int, loop_n: int) -> tuple[float, float]:
    """(batch rate, single-filter loop rate) in filter-steps/s for the UWB model."""
    from fusion import testing
    from fusion.batch import make_batch_filter

    s, models = uwb_setup()
    R, gate, proc = s.sensors["uwb"].R, s.sensors["uwb"].gate, s.process
    rng = np.random.default_rng(0)
    x0 = np.array([5.0, 4.0, 1.0, 0.5]) + rng.normal(0, 1.0, (N, 4))
    P0 = np.diag([1.0, 1.0, 0.25, 0.25])
    zs = [rng.normal(12.0, 0.1, (N, 1)) for _ in range(8)]
    bf = make_batch_filter(testing.build("filter", name))
    single = testing.build("filter", name)
    best_b = best_s = np.inf
    for _ in range(rounds):
        b = bf.initial_belief(0.0, x0, P0)
        t0, c0 = time.perf_counter(), time.process_time()
        for k in range(steps):
            b = bf.update(bf.predict(b, proc, None, 0.05), models[k % 4], zs[k % 8], R, gate).belief
        best_b = min(best_b, time.perf_counter() - t0)
        CPU[0] = min(CPU[0], time.process_time() - c0)
        bs = [single.initial_belief(0.0, x0[i], P0) for i in range(loop_n)]
        t0 = time.perf_counter()
        for k in range(steps):
            z, m = zs[k % 8], models[k % 4]
            bs = [single.update(single.predict(bb, proc, None, 0.05), m, z[i], R, gate).belief
                  for i, bb in enumerate(bs)]
        best_s = min(best_s, time.perf_counter() - t0)
    return N * steps / best_b, loop_n * steps / best_s


def bench_ins(name: str, N: int, steps: int, rounds: int, loop_n: int) -> tuple[float, float]:
    """(batch rate, single-filter loop rate) in filter-steps/s for the 16-state INS."""
    from fusion import testing
    from fusion.batch import make_batch_filter
    from tests.batch.conftest import Ranges3D

    proc = testing.build("process", "ins", {"integration": "trapezoidal"})
    meas, R = Ranges3D(), np.eye(3) * 0.05 ** 2
    params = {"batch_inputs": False} if name != "ekf" else None
    bf, single = make_batch_filter(testing.build("filter", name, params)), testing.build("filter", name, params)
    rng = np.random.default_rng(0)
    x0 = np.zeros((N, 16))
    x0[:, 0:3] = rng.normal(0, 1.0, (N, 3))
    x0[:, 6] = 1.0
    P0 = np.diag([1.0] * 3 + [0.04] * 3 + [1e-3] * 4 + [1e-4] * 3 + [1e-6] * 3)
    us = [np.concatenate([rng.normal([0, 0, -9.81], 0.3, (N, 3)), rng.normal(0, 0.05, (N, 3))], axis=1)
          for _ in range(10)]
    z = meas.h(x0) + rng.normal(0, 0.05, (N, 3))
    best_b = best_s = np.inf
    for _ in range(rounds):
        b = bf.initial_belief(0.0, x0, P0)
        t0, c0 = time.perf_counter(), time.process_time()
        for k in range(steps):
            b = bf.predict(b, proc, us[k % 10], 0.01)
            if k % 10 == 9:
                b = bf.update(b, meas, z, R, None).belief
        best_b = min(best_b, time.perf_counter() - t0)
        CPU[0] = min(CPU[0], time.process_time() - c0)
        bs = [single.initial_belief(0.0, x0[i], P0) for i in range(loop_n)]
        t0 = time.perf_counter()
        for k in range(steps):
            u = us[k % 10]
            bs = [single.predict(bb, proc, u[i], 0.01) for i, bb in enumerate(bs)]
            if k % 10 == 9:
                bs = [single.update(bb, meas, z[i], R, None).belief for i, bb in enumerate(bs)]
        best_s = min(best_s, time.perf_counter() - t0)
    return N * steps / best_b, loop_n * steps / best_s


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", default="1000", help="batch sizes, comma-separated (default 1000)")
    ap.add_argument("--steps", type=int, default=100, help="steps a round (default 100)")
    ap.add_argument("--rounds", type=int, default=3, help="rounds, best kept (default 3)")
    ap.add_argument("--loop-n", type=int, default=50, help="single filters in the reference loop (default 50)")
    ap.add_argument("--ins-chunk", type=int, default=0, help="INS batch size (default: each --n)")
    args = ap.parse_args(argv)
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; best of {args.rounds} rounds of "
          f"{args.steps} steps\n")
    print("| model | filter | N | batch filter-steps/s | (by CPU time) | loop of single filters | batch / loop |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for N in (int(v) for v in args.n.split(",")):
        for name in ("ukf", "ekf", "kf", "srukf"):
            CPU[0] = np.inf
            b, s = bench_uwb(name, N, args.steps, args.rounds, args.loop_n)
            c = N * args.steps / CPU[0]
            print(f"| 4-state UWB (pv + range) | {name} | {N} | {b:,.0f} | {c:,.0f} | {s:,.0f} | {b / s:.0f}x |",
                  flush=True)
        for name in ("ukf", "srukf", "ekf"):
            n_ins = args.ins_chunk or N
            CPU[0] = np.inf
            k = max(20, args.steps // 5)
            b, s = bench_ins(name, n_ins, k, args.rounds, max(5, args.loop_n // 5))
            c = n_ins * k / CPU[0]
            print(f"| 16-state INS + 3 ranges | {name} | {n_ins} | {b:,.0f} | {c:,.0f} | {s:,.0f} | {b / s:.0f}x |",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
