"""The smoother's cost on the shipped configs: the backward pass against the forward pass.

    python benchmarks/bench_smoother.py              # ~1 min; writes benchmarks/results/smoother.md
    python benchmarks/bench_smoother.py --repeats 1 --no-write

For every config in configs/ and each of its filter and the others that apply, in the same run and
interleaved: the plain replay (``fusion.pipeline.run``), and the smoothed replay
(``fusion.smoothing.run_smoothed``): its forward pass (the filter with the transition terms recorded)
and its backward pass (the RTS recursion plus writing the smoothed estimates and scoring them against
truth). Each is the best thread CPU time over ``--repeats`` (a busy machine slows all alike). The
target (issue 17): backward <= forward.
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "smoother.md"
CASES = [("abps_ins.yaml", "srukf"), ("abps_ins.yaml", "ukf"), ("abps_ins.yaml", "ekf"),
         ("uwb_pv_ukf.yaml", "ukf"), ("uwb_pv_ukf.yaml", "ekf"), ("uwb_pv_ukf.yaml", "kf"),
         ("uwb_pv_ukf_line.yaml", "ukf"), ("example_2d.yaml", "ukf"), ("example_2d.yaml", "srukf"),
         # the config's own filter (None: with its own parameters)
         ("imu_gps_mag_ekf.yaml", None), ("ultrasonic_3d_iekf.yaml", None), ("ultrasonic_3d_pose.yaml", None)]


def measure(config: str, filt: str, repeats: int) -> dict:
    from fusion import pipeline
    from fusion.config import load_system
    from fusion.smoothing import run_smoothed

    system = load_system(ROOT / "configs" / config, filter_override={"type": filt} if filt else None)
    lines = Path(system.recording).read_text().splitlines()
    best = {"plain": float("inf"), "forward": float("inf"), "backward": float("inf")}
    for _ in range(repeats):
        t0 = time.thread_time()
        pipeline.run(system, lines)
        best["plain"] = min(best["plain"], time.thread_time() - t0)
        marks = {}
        t0 = time.thread_time()
        res = run_smoothed(system, lines, progress=lambda t: marks.__setitem__("fwd", time.thread_time()))
        t1 = time.thread_time()
        sm = res.summary["smoothed"]
        # the backward share by wall-time proportion of the smoothed run (thread time of the whole call)
        share = sm["backward_wall_s"] / (sm["backward_wall_s"] + sm["forward_wall_s"])
        best["forward"] = min(best["forward"], (t1 - t0) * (1.0 - share))
        best["backward"] = min(best["backward"], (t1 - t0) * share)
    best["nodes"] = sm["nodes"]
    best["filter"] = system.filter.name
    best["rmse"] = (res.summary.get("errors", {}).get("position_rmse_m"), sm.get("errors", {}).get("position_rmse_m"))
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    rows = []
    for config, filt in CASES:
        m = measure(config, filt, args.repeats)
        filt = m["filter"]
        rows.append((config, filt, m))
        print(f"{config:22s} {filt:6s} plain {m['plain']:.3f} s  forward {m['forward']:.3f} s  backward "
              f"{m['backward']:.3f} s  ratio {m['backward'] / m['plain']:.2f}", flush=True)
    text = ["# Smoother cost: backward pass against forward pass", "",
            "Regenerate: `python benchmarks/bench_smoother.py` (issue 17; "
            f"{platform.machine()}, Python {platform.python_version()}, best of {args.repeats}, thread CPU time).",
            "", "*plain*: the replay without smoothing; *forward*: the smoothed run's forward pass (the filter "
            "plus the recorded transition terms); *backward*: the RTS recursion, writing the smoothed estimates "
            "and scoring them against truth. Target: backward <= plain forward. The smoothed run is one call, timed as a whole; it is split into forward and backward in the proportion of the two passes' wall times that the run reports (`smoothed.forward_wall_s`, `backward_wall_s`).", "",
            "| config | filter | nodes | plain s | forward s | backward s | backward / plain | "
            "position RMSE filtered -> smoothed (m) |", "|---|---|---:|---:|---:|---:|---:|---|"]
    for config, filt, m in rows:
        a, b = m["rmse"]
        err = f"{a:.4f} -> {b:.4f}" if a is not None and b is not None else "no truth"
        text.append(f"| {config} | {filt} | {m['nodes']:,} | {m['plain']:.3f} | {m['forward']:.3f} | "
                    f"{m['backward']:.3f} | {m['backward'] / m['plain']:.2f} | {err} |")
    if not args.no_write:
        OUT.write_text("\n".join(text) + "\n")
        print(f"wrote {OUT.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
