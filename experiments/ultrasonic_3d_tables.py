"""Paper 003 (3-D ultrasonic localiser): the tables of docs/results/ultrasonic_3d.md from the per-seed results
of experiments/ultrasonic_3d.py (Tables I-II: static positions; Table III: the Monte-Carlo walks; the
smoothed rows of issue 17). Pure formatting and statistics over seeds: no run happens here.
"""
from __future__ import annotations

import numpy as np

# Tables I and II of the paper: tape-measured position (mm), samples (cycles of four firings), the geometric
# mean (sd) and the Kalman filter's estimate (sd), mm.
POSITIONS = [  # measured x, y, z, cycles, geometric [(mean, sd) x3], filter [(est, sd) x3]
    ((1210, 1150, 1360), 111, [(1207, 7.3), (1116, 10.0), (1346, 7.1)], [(1210, 7.4), (1122, 7.5), (1357, 7.1)]),
    ((1210, 1130, 900), 68, [(1186, 7.7), (1121, 6.9), (916, 6.35)], [(1188, 8.3), (1127, 8.5), (926, 9.0)]),
    ((590, 1140, 900), 65, [(567, 8.8), (1124, 5.4), (901, 8.6)], [(569, 9.6), (1130, 7.4), (911, 8.1)]),
    ((2370, 2200, 1350), 64, [(2335, 78.1), (2077, 67.6), (1341, 15.7)], [(2341, 21.8), (2089, 19.8), (1358, 15.1)]),
    ((600, 1150, 1600), 80, [(586, 9.7), (1006, 122.0), (1577, 10.6)], [(574, 9.7), (1109, 10.1), (1593, 7.3)]),
]
# 50 rejections in the last row (80 cycles, 320 arrivals) with a 2-sigma gate, which also refuses 4.55 % of
# genuine arrivals: echo rate p with p + 0.0455 (1 - p) = 50 / 320.
GATE_OUT = 0.0455
ECHO_RATE = (50 / 320 - GATE_OUT) / (1 - GATE_OUT)
PAPER_III = {"filter": (9.34, 21.1), "geometric": (15.0, 29.7)}
SD_TARGET_MM = 10.0


def _mm(v) -> str:
    return f"{1000 * v:.0f}"


def tables_12(rows: list[list[dict]]) -> tuple[str, dict]:
    """Tables I-II (seed 1 of each position beside the paper), then the statistics over seeds."""
    lines = ["| measured (mm) | cycles | paper geometric mean (sd) | geometric mean (sd), seed 1 | paper filter (sd) "
             "| IEKF (sd), seed 1 | echoes / rejected, seed 1 |", "|---|---|---|---|---|---|---|"]
    agg = {"geo_err": [], "kf_err": [], "kf_closer": 0, "runs": 0, "kf_sd_max": 0.0, "sd_ok": 0, "bound_ok": 0, "genuine_ok": 0,
           "sd_over_bound": [], "nees": []}
    for row, runs in zip(POSITIONS, rows):
        (pos_mm, cycles, pg, pk) = row
        r = runs[0]
        geo = ", ".join(f"{_mm(m)} ({1000 * s:.1f})" for m, s in zip(r["geo_mean"], r["geo_sd"]))
        kf = ", ".join(f"{_mm(m)} ({1000 * s:.1f})" for m, s in zip(r["kf"], r["kf_sd"]))
        lines.append(f"| {', '.join(map(str, pos_mm))} | {cycles} | {', '.join(f'{m} ({s})' for m, s in pg)} | {geo} | "
                     f"{', '.join(f'{m} ({s})' for m, s in pk)} | {kf} | {r['echoes']} / {r['rejected']} |")
    lines += ["", "Over all seeds (the error is the distance from the measured position; sd and bounds are of the "
              "largest axis, mm):", "",
              "| measured (mm) | seeds | geometric error, mean (max) mm | IEKF error, mean (max) mm | IEKF closer | "
              "paper filter sd | bound, every arrival | IEKF sd, mean | bound, genuine arrivals | bound, arrivals used | "
              "IEKF sd / bound used | IEKF NEES (3 dof), mean | echoes | rejected | echoes accepted |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    agg["bound_all"] = []
    for row, runs in zip(POSITIONS, rows):
        truth = np.array(row[0]) / 1000.0
        ge = np.array([np.linalg.norm(np.array(r["geo_mean"]) - truth) for r in runs]) * 1000
        ke = np.array([np.linalg.norm(np.array(r["kf"]) - truth) for r in runs]) * 1000
        sd = np.array([max(r["kf_sd"]) for r in runs]) * 1000
        bnd = np.array([max(r["bound_sd"]) for r in runs]) * 1000
        used = np.array([max(r["bound_used_sd"]) for r in runs]) * 1000
        nees = np.array([r["nees"] for r in runs])
        closer = int((ke < ge).sum())
        b_all = 1000 * every_arrival_bound(truth, row[1])
        agg["bound_all"].append(b_all)
        agg["geo_err"] += ge.tolist()
        agg["kf_err"] += ke.tolist()
        agg["kf_closer"] += closer
        agg["runs"] += len(runs)
        agg["kf_sd_max"] = max(agg["kf_sd_max"], float(sd.max()))
        agg["sd_ok"] += int(sd.mean() <= SD_TARGET_MM)
        agg["bound_ok"] += int(b_all <= SD_TARGET_MM)
        agg["genuine_ok"] += int(bnd.mean() <= SD_TARGET_MM)
        agg["sd_over_bound"] += (sd / used).tolist()
        agg["nees"] += nees.tolist()
        echoes = sum(r["echoes"] for r in runs)
        rejected = sum(r["rejected"] for r in runs)
        lines.append(f"| {', '.join(map(str, row[0]))} | {len(runs)} | {ge.mean():.1f} ({ge.max():.1f}) | "
                     f"{ke.mean():.1f} ({ke.max():.1f}) | {closer} of {len(runs)} | {max(s for _, s in row[3])} | "
                     f"{b_all:.1f} | {sd.mean():.1f} | {bnd.mean():.1f} | {used.mean():.1f} | {np.mean(sd / used):.3f} | "
                     f"{nees.mean():.1f} | {echoes} | {rejected} | {sum(r['echoes_accepted'] for r in runs)} |")
    return "\n".join(lines), agg


def every_arrival_bound(position: np.ndarray, cycles: int, period: float = 0.225, c: float = 340.0,
                        sigma: float = 2.0e-4) -> float:
    """Largest-axis sd (m) of the Cramer-Rao bound of ``cycles`` full cycles of the four lab beacons
    (every arrival genuine and used) for a robot standing at ``position`` (m)."""
    from fusion_plugins.solvers.tdoa_geometric import stationary_bound

    lab = np.array([[0.0, 0.0, 0.0], [2.6, 0.0, 0.0], [0.0, 2.6, 0.0], [0.0, 0.0, 2.6]])
    k = np.arange(4 * cycles)
    cov = stationary_bound(lab[k % 4], position, k, c, sigma)
    return float(np.sqrt(np.diag(cov)[:3]).max())


def _stats(values: np.ndarray) -> str:
    return f"{values.mean():.2f} +- {values.std(ddof=1) if len(values) > 1 else 0.0:.2f} ({values.min():.1f}-{values.max():.1f})"


def table_3(walks: list[dict]) -> tuple[str, dict]:
    """Table III over seeds: each seed's mean and maximum over its firings; mean +- sd (range) across seeds."""
    names = [("filter", "paper's filter: orientation IEKF (static_orientation + direction), position from the "
              "position IEKF", PAPER_III["filter"]),
             ("filter_q12", "the same, process noise 1.2 deg per firing (4.4 x the variance)", None),
             ("filter_truepos", "the same, 0.57 deg, true position", None),
             ("geometric", "geometric (eqs. 12-17), last four firings, true position", PAPER_III["geometric"]),
             ("geometric_tdoa", "geometric, position from the TDOA fix of the same four firings", None),
             ("pose", "pose IEKF of configs/ultrasonic_3d_pose.yaml (all directions + cell constraint, one filter)",
              None),
             ("pose_smoothed", "the pose IEKF smoothed (Rauch-Tung-Striebel, `--smooth`; not causal)", None)]
    lines = ["| estimator | paper mean / max (deg) | mean (deg) over seeds: mean +- sd (range) | max (deg) over seeds: "
             "mean +- sd (range) | 99.9th percentile, mean | seeds with max <= paper's | per seed: mean / max |",
             "|---|---|---|---|---|---|---|"]
    agg = {}
    for key, label, paper in names:
        if not all(key in w for w in walks):
            continue
        means = np.array([w[key].mean() for w in walks])
        maxes = np.array([w[key].max() for w in walks])
        p999 = np.array([np.percentile(w[key], 99.9) for w in walks])
        agg[key] = {"mean": float(means.mean()), "max": float(maxes.mean()), "means": means.tolist(),
                    "maxes": maxes.tolist(), "p999": p999.tolist(),
                    "max_sd": float(maxes.std(ddof=1)) if len(maxes) > 1 else 0.0}
        ref = paper if paper else PAPER_III["filter"]
        below = f"{int((maxes <= ref[1]).sum())} of {len(maxes)}" if paper or key.startswith(("filter", "pose")) else "-"
        per = "; ".join(f"{m:.2f} / {x:.1f}" for m, x in zip(means, maxes))
        lines.append(f"| {label} | {'%.2f / %.1f' % paper if paper else '-'} | {_stats(means)} | {_stats(maxes)} | "
                     f"{p999.mean():.1f} | {below} | {per} |")
    return "\n".join(lines), agg


def table_smooth(walks: list[dict]) -> tuple[str, dict]:
    """Issue 17: filtered against smoothed position RMSE and NEES over the walks, both configs."""
    lines = ["| config | seeds | filtered position RMSE (mm), mean +- sd | smoothed (mm) | reduction, mean | "
             "seeds smoothed < filtered | filtered NEES | smoothed NEES | NEES dof |", "|---|---|---|---|---|---|---|---|---|"]
    agg = {}
    for key, cfg in (("iekf", "ultrasonic_3d_iekf.yaml"), ("pose", "ultrasonic_3d_pose.yaml")):
        rows = [w[f"{key}_smooth"] for w in walks if f"{key}_smooth" in w]
        if not rows:
            continue
        f = np.array([r["filtered_rmse"] for r in rows]) * 1000
        s = np.array([r["smoothed_rmse"] for r in rows]) * 1000
        red = 1.0 - s / f
        fn = np.mean([r["filtered_nees"] for r in rows])
        sn = np.mean([r["smoothed_nees"] for r in rows])
        agg[key] = {"filtered": float(f.mean()), "smoothed": float(s.mean()), "reduction": float(red.mean())}
        lines.append(f"| {cfg} | {len(rows)} | {f.mean():.1f} +- {f.std(ddof=1) if len(f) > 1 else 0:.1f} | "
                     f"{s.mean():.1f} +- {s.std(ddof=1) if len(s) > 1 else 0:.1f} | {100 * red.mean():.1f} % | "
                     f"{int((s < f).sum())} of {len(f)} | {fn:.2f} | {sn:.2f} | {rows[0]['nees_dof']} |")
    return "\n".join(lines), agg
