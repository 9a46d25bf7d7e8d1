"""Smoothed against filtered over many seeds on every shipped system with truth (issue 17), and the
smoother's cost; writes docs/results/smoothing.md.

    python experiments/smoother_seeds.py                 # 50 seeds each, ~10 min on 1 core
    python experiments/smoother_seeds.py --seeds 10      # quicker

For each (config, scenario) pair, each seed simulates the scenario's recording with that seed
(``fusion.simulate``: same trajectory, new noise and faults), replays it through the config
(``fusion.smoothing.run_smoothed``: the forward filter, then the RTS backward pass) and scores the
filtered and the smoothed estimates against the same truth (the config's own evaluation: horizontal
position for abps_ins). Reported per system: the mean and the spread of the two position RMSEs, the
reduction (1 - smoothed / filtered; mean, 5th percentile), the seeds where smoothing helped, and the
NEES of both with the fraction inside its 95% chi-square interval; and the wall times of the two passes
(median over seeds). The timing table of benchmarks/bench_smoother.py is the careful one.
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "results" / "smoothing.md"
NOTE = ("abps_ins: the smoothed NEES is above its 15 dof (the filter's is not); on recordings/abps_mine.log the position block is 5.6 against 3 (filtered 2.9), velocity 3.9 against 3, the biases below 3: the smoothed position covariance is too small by about 2x. Not the cause (tried): the sigma-point batching of the IMU runs (the EKF smoother, composed sample by sample, gives the same overall NEES: 16.6 against the srukf smoother's 16.6), the trilateration window, projecting the quaternion block's covariance onto the unit sphere's tangent space. Most of it is a deterministic floor: on the same scenario simulated without noise (`fusion simulate scenarios/abps_mine.yaml --noise off`) the filter's horizontal RMSE is 0.025 m and the smoother's 0.013 m (NEES 3.6 and 6.5): errors of the models against the simulator that no covariance carries, about half of the smoother's 0.027 m with noise, and large against its smaller covariance.")
SYSTEMS = [  # config, scenario
    ("abps_ins.yaml", "abps_mine.yaml"),
    ("uwb_pv_ukf.yaml", "uwb_route1.yaml"),
    ("uwb_pv_ukf.yaml", "uwb_route2.yaml"),
    ("uwb_pv_ukf_line.yaml", "uwb_route1_line.yaml"),
    ("example_2d.yaml", "example_2d.yaml"),
]


def one(config: str, scenario: str, seed: int) -> dict:
    from fusion.config import load_system
    from fusion.simulate.engine import simulate_file
    from fusion.smoothing import run_smoothed

    system = load_system(ROOT / "configs" / config)
    lines = simulate_file(str(ROOT / "scenarios" / scenario), seed=seed).splitlines()
    res = run_smoothed(system, lines)
    s, sm = res.summary, res.summary["smoothed"]
    return {"filtered": s["errors"]["position_rmse_m"], "smoothed": sm["errors"]["position_rmse_m"],
            "nees_f": s["consistency"]["nees_mean"], "nees_s": sm["consistency"]["nees_mean"],
            "in95_f": s["consistency"]["nees_in_95_fraction"], "in95_s": sm["consistency"]["nees_in_95_fraction"],
            "dof": s["consistency"]["nees_dof"], "forward_s": sm["forward_wall_s"], "backward_s": sm["backward_wall_s"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    table = []
    t_start = time.time()
    for config, scenario in SYSTEMS:
        rows = [one(config, scenario, s) for s in seeds]
        f = np.array([r["filtered"] for r in rows])
        sm = np.array([r["smoothed"] for r in rows])
        red = 1.0 - sm / f
        out = {"config": config, "scenario": scenario, "n": len(rows), "f_mean": f.mean(), "f_sd": f.std(ddof=1) if len(f) > 1 else 0.0,
               "s_mean": sm.mean(), "s_sd": sm.std(ddof=1) if len(sm) > 1 else 0.0, "red_mean": red.mean(),
               "red_p5": np.percentile(red, 5), "helped": int((sm < f).sum()), "dof": rows[0]["dof"],
               "nees_f": np.mean([r["nees_f"] for r in rows]), "nees_s": np.mean([r["nees_s"] for r in rows]),
               "in95_f": np.mean([r["in95_f"] for r in rows]), "in95_s": np.mean([r["in95_s"] for r in rows]),
               "fwd": np.median([r["forward_s"] for r in rows]), "bwd": np.median([r["backward_s"] for r in rows])}
        table.append(out)
        print(f"{config} / {scenario}: filtered {out['f_mean']:.4f} m, smoothed {out['s_mean']:.4f} m, "
              f"reduction {100 * out['red_mean']:.1f}% (p5 {100 * out['red_p5']:.1f}%), helped {out['helped']}/{out['n']}, "
              f"NEES {out['nees_f']:.2f} -> {out['nees_s']:.2f} (dof {out['dof']})", flush=True)
    lines = ["# Smoothing: filtered against smoothed over many seeds", "",
             f"Regenerate: `python experiments/smoother_seeds.py --seeds {args.seeds}` (issue 17; seeds "
             f"{seeds.start}-{seeds.stop - 1}; {platform.machine()}, Python {platform.python_version()}; "
             f"{(time.time() - t_start) / 60:.1f} min). Timing: `python benchmarks/bench_smoother.py` "
             "(benchmarks/results/smoother.md).", "",
             "Each seed re-simulates the scenario (same trajectory, new noise and faults), runs the config's "
             "filter forward and the Rauch-Tung-Striebel smoother backward (`fusion run CONFIG --smooth`), and "
             "scores both against the same truth with the config's own evaluation (abps_ins: horizontal position).", "",
             "## Position RMSE", "",
             "| config | scenario | seeds | filtered RMSE (m), mean +- sd | smoothed RMSE (m) | reduction, mean | "
             "reduction, 5th pct | seeds smoothed < filtered |", "|---|---|---:|---|---|---:|---:|---:|"]
    for o in table:
        lines.append(f"| {o['config']} | {o['scenario']} | {o['n']} | {o['f_mean']:.4f} +- {o['f_sd']:.4f} | "
                     f"{o['s_mean']:.4f} +- {o['s_sd']:.4f} | {100 * o['red_mean']:.1f}% | {100 * o['red_p5']:.1f}% | "
                     f"{o['helped']}/{o['n']} |")
    lines += ["", "## Consistency (NEES, mean over seeds of each run's mean; fraction inside the 95% chi-square "
              "interval of one sample)", "",
              "| config | scenario | dof | filtered NEES | smoothed NEES | filtered in 95% | smoothed in 95% |",
              "|---|---|---:|---:|---:|---:|---:|"]
    for o in table:
        lines.append(f"| {o['config']} | {o['scenario']} | {o['dof']} | {o['nees_f']:.2f} | {o['nees_s']:.2f} | "
                     f"{o['in95_f']:.3f} | {o['in95_s']:.3f} |")
    lines += ["", NOTE]
    lines += ["", "## Wall time (median over seeds, s)", "", "| config | scenario | forward | backward | backward / forward |",
              "|---|---|---:|---:|---:|"]
    for o in table:
        lines.append(f"| {o['config']} | {o['scenario']} | {o['fwd']:.2f} | {o['bwd']:.2f} | {o['bwd'] / o['fwd']:.2f} |")
    lines += ["", "The forward time includes recording the transition terms (and, for the UKF, drawing the "
              "prediction's sigma points a second time for the cross-covariance); backward includes writing "
              "the smoothed estimates and scoring them."]
    if not args.no_write:
        OUT.write_text("\n".join(lines) + "\n")
        print(f"wrote {OUT.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
