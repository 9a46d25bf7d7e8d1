"""The 16-state SR-UKF of paper 000 (configs/abps_ins.yaml): microseconds per IMU prediction and per ABPS
update, and the whole replay of recordings/abps_mine.log as a multiple of real time.

    python benchmarks/bench_abps.py                  # ~30 s
    python benchmarks/bench_abps.py --repeats 3 --rounds 10

Step costs are measured on the belief, IMU samples and fix of the real run (the 150th fix), beside
FilterPy's UnscentedKalmanFilter on the same ``ins`` and ``position`` models (MerweScaledSigmaPoints,
same alpha, beta, kappa; Q(x, u, dt) at its prior mean before each predict), all interleaved round by
round, each keeping its best round (a busy machine slows all alike):

* ``srukf, batched``: ``predict_inputs`` of one ABPS cycle of IMU samples (40 at 100 Hz: what the
  scheduler passes between two fixes), divided by the number of samples;
* ``srukf, per sample``: ``predict`` of one sample (``batch_inputs: false``, and what FilterPy does);
* the ABPS update: ``update`` with a position fix through the lever arm (eq. 53), m = 3.

The replay runs ``fusion run`` 's own path (parse, decode, schedule, filter: fusion.pipeline.run)
``--repeats`` times; the best thread CPU time and the best wall time over the recording's duration give
the multiple of real time. Parse alone (fusion.logformat.iter_messages over the file) is timed too.
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")        # as the CLI: tiny matrices, BLAS threads only add latency

import argparse  # noqa: E402
import gc  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "abps_ins.yaml"


def replay_speed(config: Path = CONFIG, repeats: int = 5) -> dict:
    """Best-of-``repeats`` CPU and wall time of the whole replay; ``x_real_time`` = data duration / time."""
    from fusion import pipeline
    from fusion.config import load_system
    from fusion.logformat import ParsedStream, iter_messages
    from fusion.sources.recording import open_lines

    best = {"cpu_s": float("inf"), "wall_s": float("inf"), "parse_cpu_s": float("inf")}
    summary = None
    for _ in range(repeats):
        system = load_system(config)
        gc.collect()
        c0, w0 = time.process_time(), time.perf_counter()
        result = pipeline.run(system, system.recording)
        best["cpu_s"] = min(best["cpu_s"], time.process_time() - c0)
        best["wall_s"] = min(best["wall_s"], time.perf_counter() - w0)
        if summary is None:
            summary = result.summary
            meta = result.parsed.header.meta
            data_s = float(meta["duration"]) if "duration" in meta else summary["duration_s"]
        c0 = time.process_time()
        for _ in iter_messages(open_lines(system.recording), ParsedStream()):
            pass
        best["parse_cpu_s"] = min(best["parse_cpu_s"], time.process_time() - c0)
    duration = data_s                    # the recording's span (the estimates start after the alignment)
    return {**best, "duration_s": duration, "x_real_time_cpu": duration / best["cpu_s"],
            "x_real_time_wall": duration / best["wall_s"], "steps": summary["steps"],
            "batched_predicts": summary.get("filter_counters", {}).get("batched_predicts", 0),
            "imu_samples": summary["sensors"]["imu"]["used"]}


def _setup(config: Path = CONFIG, index: int = 150):
    """Belief, models, a cycle of IMU samples and a fix from the real run."""
    from fusion import pipeline
    from fusion.config import load_system

    system = load_system(config)
    kept = pipeline.Collect()
    pipeline.run(system, system.recording, [kept])
    est = [e for e in kept.estimates if e.update is not None][index]
    rng = np.random.default_rng(0)
    u0 = np.array([0.05, 0.02, -9.80, 0.002, -0.003, 0.15])
    us = u0 + rng.normal(size=(40, 6)) * [0.05, 0.05, 0.05, 0.01, 0.01, 0.01]
    sensor = system.sensors["abps"]
    z = sensor.model.h(est.belief.x) + np.array([0.03, -0.02, 0.05])
    R = np.diag([0.0025, 0.0025, 0.09])
    return system, est.belief, us, np.full(40, 0.01), sensor.model, z, R


def step_costs(rounds: int = 20, calls: int = 50, config: Path = CONFIG) -> dict:
    """us per IMU prediction (batched and per sample), per ABPS update, and FilterPy's UKF alike."""
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    from fusion.registry import default_registry

    system, belief, us, dts, model, z, R = _setup(config)
    process = system.process
    reg = default_registry()
    p = system.filter.params
    batched = reg.get("filter", "srukf")(reg.get("filter", "srukf").Params(**p.model_dump()))
    single = reg.get("filter", "srukf")(reg.get("filter", "srukf").Params(**{**p.model_dump(), "batch_inputs": False}))
    ukf = reg.get("filter", "ukf")(reg.get("filter", "ukf").Params(alpha=p.alpha, beta=p.beta, kappa=p.kappa))
    ub = ukf.initial_belief(belief.t, belief.x, belief.cov)
    k = len(dts)
    n = belief.x.shape[0]
    fp = UnscentedKalmanFilter(n, 3, 0.01, model.h, lambda x, dt: process.f(x, us[0], dt),
                               MerweScaledSigmaPoints(n, p.alpha, p.beta, p.kappa))
    fp.R = R
    x0, P0 = belief.x.copy(), belief.cov.copy()

    def fp_predict():
        for _ in range(calls):
            fp.x, fp.P = x0.copy(), P0.copy()
            fp.Q = process.Q(fp.x, us[0], 0.01)
            fp.predict()

    def fp_update():
        for _ in range(calls):
            fp.x, fp.P = x0.copy(), P0.copy()
            fp.sigmas_f = fp.points_fn.sigma_points(x0, P0)
            fp.update(z)

    def fp_reset():
        for _ in range(calls):
            fp.x, fp.P = x0.copy(), P0.copy()
            fp.sigmas_f = fp.points_fn.sigma_points(x0, P0)

    runners = {
        "srukf batched predict (per IMU sample)": (lambda: [batched.predict_inputs(belief, process, us, dts) for _ in range(calls)], calls * k),
        "srukf per-sample predict": (lambda: [single.predict(belief, process, us[0], 0.01) for _ in range(calls)], calls),
        "srukf ABPS update": (lambda: [batched.update(belief, model, z, R) for _ in range(calls)], calls),
        "ukf batched predict (per IMU sample)": (lambda: [ukf.predict_inputs(ub, process, us, dts) for _ in range(calls)], calls * k),
        "ukf ABPS update": (lambda: [ukf.update(ub, model, z, R) for _ in range(calls)], calls),
        "FilterPy UKF predict (per IMU sample)": (fp_predict, calls),
        "FilterPy UKF update": (fp_update, calls),
        "_fp_reset": (fp_reset, calls),
    }
    best = {name: float("inf") for name in runners}
    gc_was = gc.isenabled()
    gc.disable()
    try:
        for name, (fn, _) in runners.items():
            fn()
        for _ in range(rounds):
            for name, (fn, _) in runners.items():
                t0 = time.thread_time()
                fn()
                best[name] = min(best[name], time.thread_time() - t0)
    finally:
        if gc_was:
            gc.enable()
    out = {name: best[name] / count * 1e6 for name, (_, count) in runners.items()}
    out["FilterPy UKF update"] -= out.pop("_fp_reset")
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5, help="replays (best kept)")
    ap.add_argument("--rounds", type=int, default=20, help="rounds of the step timings (best kept)")
    args = ap.parse_args(argv)
    steps = step_costs(args.rounds)
    print(f"{'step (thread CPU time, best of ' + str(args.rounds) + ' rounds)':55s} {'us':>8s}")
    for name, us_ in steps.items():
        print(f"{name:55s} {us_:8.1f}")
    fp = steps["FilterPy UKF predict (per IMU sample)"] + steps["FilterPy UKF update"]
    ours = steps["srukf per-sample predict"] + steps["srukf ABPS update"]
    print(f"FilterPy UKF / srukf per predict + update (per sample): {fp / ours:.1f}x")
    cyc_fp = 40 * steps["FilterPy UKF predict (per IMU sample)"] + steps["FilterPy UKF update"]
    cyc = 40 * steps["srukf batched predict (per IMU sample)"] + steps["srukf ABPS update"]
    print(f"one ABPS cycle (40 IMU samples + 1 fix): srukf {cyc:.0f} us, FilterPy UKF {cyc_fp:.0f} us ({cyc_fp / cyc:.1f}x)")
    r = replay_speed(repeats=args.repeats)
    print(f"replay of {r['duration_s']:.1f} s of data ({r['imu_samples']} IMU samples, {r['steps']['update']} fixes, "
          f"{r['batched_predicts']} batched predictions): best CPU {r['cpu_s']:.3f} s "
          f"({r['x_real_time_cpu']:.0f}x real time), best wall {r['wall_s']:.3f} s ({r['x_real_time_wall']:.0f}x); "
          f"parsing alone {r['parse_cpu_s']:.3f} s CPU")
    return {"steps": steps, "replay": r}


if __name__ == "__main__":
    main()
