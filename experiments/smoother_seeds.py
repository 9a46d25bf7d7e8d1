"""Smoothed against filtered over many seeds on every shipped system with truth (issue 17), and the
smoother's cost; writes docs/results/smoothing.md.

    python experiments/smoother_seeds.py                 # 50 seeds each, ~15 min on 1 core
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
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "experiments"))
import abps_smoothed  # noqa: E402  (experiments/, on the path above)

OUT = ROOT / "docs" / "results" / "smoothing.md"
FLAT = "abps_mine.yaml, flat floor"  # experiments/abps_smoothed.flat_scenario: the known height is true
SYSTEMS = [  # config, scenario
    ("abps_ins.yaml", "abps_mine.yaml"),
    ("abps_ins.yaml", FLAT),
    ("uwb_pv_ukf.yaml", "uwb_route1.yaml"),
    ("uwb_pv_ukf.yaml", "uwb_route2.yaml"),
    ("uwb_pv_ukf_line.yaml", "uwb_route1_line.yaml"),
    ("example_2d.yaml", "example_2d.yaml"),
    ("ultrasonic_3d_iekf.yaml", "ultrasonic_3d_walk.yaml"),
    ("ultrasonic_3d_pose.yaml", "ultrasonic_3d_walk.yaml"),
]


def one(config: str, scenario: str, seed: int, tmp: Path) -> dict:
    """One seed: the summary's filtered and smoothed scores; for abps_ins also the NEES of the p and v blocks
    and of pz alone (experiments/abps_smoothed.py), where the smoothed NEES exceeds its dof."""
    from fusion.config import load_system
    from fusion.metrics import Truth
    from fusion.simulate.engine import simulate_file
    from fusion.smoothing import run_smoothed

    system = load_system(ROOT / "configs" / config)
    path = abps_smoothed.flat_scenario(tmp) if scenario == FLAT else ROOT / "scenarios" / scenario
    text = simulate_file(str(path), seed=seed)
    extra = {}
    if config == "abps_ins.yaml":
        log = tmp / "run.log"
        log.write_text(text)
        f, sm_rows, s = abps_smoothed.both(system, str(log), Truth.from_recording(log))
        bf, bs = abps_smoothed.brief(f), abps_smoothed.brief(sm_rows)
        extra = {"p_f": bf["block_nees"]["p"], "p_s": bs["block_nees"]["p"], "v_f": bf["block_nees"]["v"],
                 "v_s": bs["block_nees"]["v"], "rest_f": sum(bf["block_nees"][k] for k in ("attitude", "ba", "bw")),
                 "rest_s": sum(bs["block_nees"][k] for k in ("attitude", "ba", "bw")),
                 "pz_f": float(bf["el"][2]), "pz_s": float(bs["el"][2])}
    else:
        s = run_smoothed(system, text.splitlines()).summary
    sm = s["smoothed"]
    return {**extra, "filtered": s["errors"]["position_rmse_m"], "smoothed": sm["errors"]["position_rmse_m"],
            "nees_f": s["consistency"]["nees_mean"], "nees_s": sm["consistency"]["nees_mean"],
            "in95_f": s["consistency"]["nees_in_95_fraction"], "in95_s": sm["consistency"]["nees_in_95_fraction"],
            "dof": s["consistency"]["nees_dof"], "forward_s": sm["forward_wall_s"], "backward_s": sm["backward_wall_s"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--only", help="configs whose name contains this (a quick look; implies --no-write)")
    args = ap.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    table = []
    t_start = time.time()
    for config, scenario in [x for x in SYSTEMS if not args.only or args.only in x[0]]:
        with tempfile.TemporaryDirectory() as d:
            rows = [one(config, scenario, s, Path(d)) for s in seeds]
        f = np.array([r["filtered"] for r in rows])
        sm = np.array([r["smoothed"] for r in rows])
        red = 1.0 - sm / f
        out = {"config": config, "scenario": scenario, "n": len(rows), "f_mean": f.mean(), "f_sd": f.std(ddof=1) if len(f) > 1 else 0.0,
               "s_mean": sm.mean(), "s_sd": sm.std(ddof=1) if len(sm) > 1 else 0.0, "red_mean": red.mean(),
               "red_p5": np.percentile(red, 5), "helped": int((sm < f).sum()), "dof": rows[0]["dof"],
               "nees_f": np.mean([r["nees_f"] for r in rows]), "nees_s": np.mean([r["nees_s"] for r in rows]),
               "in95_f": np.mean([r["in95_f"] for r in rows]), "in95_s": np.mean([r["in95_s"] for r in rows]),
               "fwd": np.median([r["forward_s"] for r in rows]), "bwd": np.median([r["backward_s"] for r in rows])}
        if "p_f" in rows[0]:
            out["blocks"] = {k: float(np.mean([r[k] for r in rows]))
                             for k in ("p_f", "p_s", "v_f", "v_s", "rest_f", "rest_s", "pz_f", "pz_s")}
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
    lines += ["", "abps_ins per block (mean NEES over the seeds; dof 3 for p and v, 9 for attitude + ba + bw; pz: its "
              "squared error over its variance, 1 if consistent):", "",
              "| scenario | p filtered | p smoothed | v filtered | v smoothed | att+ba+bw filtered | smoothed | pz filtered | pz smoothed |",
              "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for o in table:
        if "blocks" in o:
            b = o["blocks"]
            lines.append(f"| {o['scenario']} | {b['p_f']:.2f} | {b['p_s']:.2f} | {b['v_f']:.2f} | {b['v_s']:.2f} | "
                         f"{b['rest_f']:.2f} | {b['rest_s']:.2f} | {b['pz_f']:.2f} | {b['pz_s']:.2f} |")
    lines += ["", "The abps_ins smoothed NEES above 15 on the shipped scenario is its vertical channel (pz, then vz): the "
              "config takes the receiver height as known (-0.75 m, the 2-D fix of paper 000) while the scenario's floor "
              "dips, so each fix's z is off by up to 0.13 m, slowly along the route, and the config treats that as "
              "independent noise of sd 0.3 m, three times its size so that the filter stays consistent. The smoother "
              "averages the fixes on both sides of each time, and a slowly changing error does not average out. On the "
              "same route with a flat floor (the assumption true; `abps_mine.yaml, flat floor`, made by "
              "experiments/abps_smoothed.py) the smoothed position block and NEES are back within their dof: the "
              "smoother is consistent where the model is. Recovery resets (the chain breaks, G = 0) did not occur in "
              "these runs. What would fix the model: docs/results/abps_ins.md, section Filtered against smoothed."
              " The ultrasonic configs (paper 003) are not explained here: ultrasonic_3d_pose's smoothed NEES is above its dof while the filter's is not, and ultrasonic_3d_iekf's filtered NEES is already above its dof (the smoothed one inherits it); both are open."]
    lines += ["", "## Wall time (median over seeds, s)", "", "| config | scenario | forward | backward | backward / forward |",
              "|---|---|---:|---:|---:|"]
    for o in table:
        lines.append(f"| {o['config']} | {o['scenario']} | {o['fwd']:.2f} | {o['bwd']:.2f} | {o['bwd'] / o['fwd']:.2f} |")
    lines += ["", "The forward time includes recording the transition terms (and, for the UKF, drawing the "
              "prediction's sigma points a second time for the cross-covariance); backward includes writing "
              "the smoothed estimates and scoring them."]
    if not (args.no_write or args.only):
        OUT.write_text("\n".join(lines) + "\n")
        print(f"wrote {OUT.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
