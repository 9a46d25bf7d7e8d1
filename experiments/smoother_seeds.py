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


POSE_TEXT = ("ultrasonic_3d_pose (paper 003): the smoothed excess is the attitude block, not the position (per block at the "
             "end of this paragraph). The direction model's error is the receivers' discretisation (the closest of 32 normals, cells "
             "of ~37 deg): the same pulse after pulse while a beacon's direction stays in one cell (~150 of its "
             "pulses). The config gives it as white noise of sd 30 deg (and the attitude walk 0.8 deg per firing "
             "instead of the true 0.57) so that the filter, averaging a limited past, is consistent; the smoother "
             "averages both sides, about twice the data, and a correlated error does not average out: the mechanism "
             "of abps_ins's height before hz. Not the smoother's quaternion handling: on an attitude random walk seen "
             "through white attitude fixes, simulated as both models state (tests/smoothing/test_quaternion_smoothing.py, "
             "20 seeds), the smoothed attitude NEES is 2.89 on 3 dof (filtered 2.88) with the EKF and the SR-UKF. The "
             "fix on principle, not made yet: the discretisation error of each beacon's direction as a state (a "
             "Gauss-Markov block of 2 dof per beacon, correlated over the time a direction stays in a cell), which "
             "needs the direction model and the firing_clock process to carry it. Cheaper remedies measured on 4 "
             "seeds and rejected: sd 60 deg (attitude NEES 1.5 filtered, 2.3 smoothed: the filter then under-"
             "confident), the cell constraint alone (attitude NEES 6.5 filtered: the 1 deg constraint over-confident).")
IEKF_TEXT = ("ultrasonic_3d_iekf: position only (3 dof). Part of its filtered excess is the paper's 2-sigma echo gate: a "
             "good arrival time with a large innovation (5% of them) is refused, and an error that the refused "
             "measurement would have corrected stays while the covariance does not grow for it; with a 3-sigma gate "
             "the position NEES over seeds 100-103 is 3.01 instead of 3.20 (4 seeds: not a result, a direction). The "
             "gate is the paper's and is kept; the rest is not explained here.")
MIN_IN95 = 0.90   # criterion 2 of the consistency table (see the page)


def mean_interval(dof: int, seeds: int) -> tuple[float, float]:
    """95% interval of the average over ``seeds`` independent chi2(dof) run means: d +- 1.96 sqrt(2 d / S)."""
    h = 1.96 * np.sqrt(2.0 * dof / seeds)
    return dof - h, dof + h


def verdict(o: dict, which: str) -> str:
    """'yes', or what fails: 'mean low' / 'mean high' (criterion 1), 'fraction' (criterion 2)."""
    lo, hi = mean_interval(o["dof"], o["n"])
    m = o["nees_" + which]
    bad = (["mean low"] if m < lo else ["mean high"] if m > hi else []) + (["fraction"] if o["in95_" + which] < MIN_IN95 else [])
    return "yes" if not bad else "no: " + ", ".join(bad)


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
    elif config == "ultrasonic_3d_pose.yaml":
        from fusion import pipeline
        import pose_blocks

        log = tmp / "run.log"
        log.write_text(text)
        truth = Truth.from_recording(log)
        fwd, smc = pipeline.Collect(), pipeline.Collect()
        s = run_smoothed(system, str(log), [smc], forward_sinks=[fwd]).summary
        bf, bs = pose_blocks.block_nees(fwd.estimates, truth, system.layout), pose_blocks.block_nees(smc.estimates, truth, system.layout)
        extra = {"p_f": bf["p"], "p_s": bs["p"], "att_f": bf["attitude"], "att_s": bs["attitude"]}
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
    ap.add_argument("--json", help="also write the table's numbers here")
    ap.add_argument("--from-json", help="write the page from numbers a --json run saved (no runs)")
    ap.add_argument("--minutes", type=float, help="with --from-json: the saved run's duration for the header")
    args = ap.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    table = []
    pose_line = ""
    t_start = time.time()
    todo = [x for x in SYSTEMS if not args.only or args.only in x[0]]
    if args.from_json:
        import json

        table = json.loads(Path(args.from_json).read_text())
        todo = []
    for config, scenario in todo:
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
        if "pz_f" in rows[0]:
            out["blocks"] = {k: float(np.mean([r[k] for r in rows]))
                             for k in ("p_f", "p_s", "v_f", "v_s", "rest_f", "rest_s", "pz_f", "pz_s")}
        if "att_f" in rows[0]:
            out["pose_blocks"] = {k: float(np.mean([r[k] for r in rows])) for k in ("p_f", "p_s", "att_f", "att_s")}
        table.append(out)
        print(f"{config} / {scenario}: filtered {out['f_mean']:.4f} m, smoothed {out['s_mean']:.4f} m, "
              f"reduction {100 * out['red_mean']:.1f}% (p5 {100 * out['red_p5']:.1f}%), helped {out['helped']}/{out['n']}, "
              f"NEES {out['nees_f']:.2f} -> {out['nees_s']:.2f} (dof {out['dof']})", flush=True)
    lines = ["# Smoothing: filtered against smoothed over many seeds", "",
             f"Regenerate: `python experiments/smoother_seeds.py --seeds {args.seeds}` (issue 17; seeds "
             f"{seeds.start}-{seeds.stop - 1}; {platform.machine()}, Python {platform.python_version()}; "
             f"{args.minutes if args.from_json else (time.time() - t_start) / 60:.1f} min). Timing: `python benchmarks/bench_smoother.py` "
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
    lines += ["", "## Consistency", "",
              "What \"inside its chi-square bounds\" means here (issue 17). Over S seeded runs of T samples, the mean "
              "NEES of dof d inside the 95% interval of chi2(S T d) / (S T) would hold only if the samples of a run "
              "were independent; they are not (the error at one update is most of the error at the next), so that "
              "interval is far too narrow. Two criteria instead, both required:", "",
              f"1. **mean**: each run's mean NEES, averaged over the S seeds, inside d +- 1.96 sqrt(2 d / S), the 95% "
              "interval of the average of S independent chi2(d) run means (a run's mean of correlated samples spreads "
              "at most like one sample; this is the conservative reading);",
              f"2. **fraction**: the fraction of samples inside the per-sample 95% chi-square interval at least "
              f"{MIN_IN95:.2f} (at most twice the nominal 5% outside; an over- or under-confident estimate both leave it).", "",
              "\"mean low\" is under-confidence (the covariance larger than the errors: the UWB and example configs' "
              "filters, and abps_ins's attitude and bias blocks, below), the safe side; \"mean high\" over-confidence.", "",
              "| config | scenario | dof | interval of the mean | filtered NEES | smoothed NEES | filtered in 95% | "
              "smoothed in 95% | filtered passes | smoothed passes |",
              "|---|---|---:|---|---:|---:|---:|---:|---|---|"]
    for o in table:
        lo, hi = mean_interval(o["dof"], o["n"])
        lines.append(f"| {o['config']} | {o['scenario']} | {o['dof']} | {lo:.2f} - {hi:.2f} | {o['nees_f']:.2f} | "
                     f"{o['nees_s']:.2f} | {o['in95_f']:.3f} | {o['in95_s']:.3f} | {verdict(o, 'f')} | {verdict(o, 's')} |")
    lines += ["", "abps_ins per block (mean NEES over the seeds; dof 3 for p and v, 9 for attitude + ba + bw; pz: its "
              "squared error over its variance, 1 if consistent):", "",
              "| scenario | p filtered | p smoothed | v filtered | v smoothed | att+ba+bw filtered | smoothed | pz filtered | pz smoothed |",
              "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for o in table:
        if "pose_blocks" in o:
            b = o["pose_blocks"]
            pose_line = (f"ultrasonic_3d_pose per block (mean NEES over the seeds, 3 dof each): position {b['p_f']:.2f} "
                         f"filtered, {b['p_s']:.2f} smoothed; attitude {b['att_f']:.2f} filtered, {b['att_s']:.2f} smoothed.")
    for o in table:
        if "blocks" in o:
            b = o["blocks"]
            lines.append(f"| {o['scenario']} | {b['p_f']:.2f} | {b['p_s']:.2f} | {b['v_f']:.2f} | {b['v_s']:.2f} | "
                         f"{b['rest_f']:.2f} | {b['rest_s']:.2f} | {b['pz_f']:.2f} | {b['pz_s']:.2f} |")
    lines += ["", "abps_ins: until issue 17 the config took the receiver height as known (-0.75 m, the 2-D fix of paper 000) "
              "and gave each fix its error, up to 0.13 m as the scenario's floor dips, slowly along the route, as white "
              "noise of sd 0.3 m; the smoother, which averages the fixes on both sides of each time, was then over-"
              "confident in pz (over these 50 seeds: smoothed NEES 16.81, pz 2.90 where 1 is consistent; filtered 13.70). "
              "The height error is now a state of the model, hz: a first-order Gauss-Markov block of the ins process "
              "(sd 0.1 m, tau 10 s, chosen from the floor's dip and the vehicle's pace, configs/abps_ins.yaml) that the "
              "position model adds to the fix's z (offset_block), with z_sd 0.05 m for what each fix adds afresh. On the "
              "same route with a flat floor (`abps_mine.yaml, flat floor`, experiments/abps_smoothed.py) the assumption "
              "is true: the control. Recovery resets (the chain breaks, G = 0) did not occur in these runs.", "",
              POSE_TEXT + " " + pose_line, "", IEKF_TEXT]
    lines += ["", "## Wall time (median over seeds, s)", "", "| config | scenario | forward | backward | backward / forward |",
              "|---|---|---:|---:|---:|"]
    for o in table:
        lines.append(f"| {o['config']} | {o['scenario']} | {o['fwd']:.2f} | {o['bwd']:.2f} | {o['bwd'] / o['fwd']:.2f} |")
    lines += ["", "The forward time includes recording the transition terms (and, for the UKF, drawing the "
              "prediction's sigma points a second time for the cross-covariance); backward includes writing "
              "the smoothed estimates and scoring them."]
    if args.json:
        import json

        Path(args.json).write_text(json.dumps(table, indent=1, default=float))
    if not (args.no_write or args.only):
        OUT.write_text("\n".join(lines) + "\n")
        print(f"wrote {OUT.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
