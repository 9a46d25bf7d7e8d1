"""Position and attitude NEES apart, for the pose filter of paper 003 (configs/ultrasonic_3d_pose.yaml):
used by experiments/smoother_seeds.py to say which block makes the smoothed NEES exceed its dof.

The attitude error is the body-frame rotation ``2 vec(q_true^-1 (x) q_est)`` (rad), its covariance the
quaternion block's mapped by the same linearisation (as experiments/abps_smoothed.py does for the INS).

Run alone it measures a config, or a variant of it, over seeds (``--set``: process/model/initial-sd
overrides; ``--vary-trajectory``: a new walk per seed, not only new noise: the scenario's walk is fixed, so
over its seeds the receivers' sequence, hence the directions' discretisation errors, are nearly the same)::

    python experiments/pose_blocks.py --seeds 50 --jobs 2

Issue 17, the directions' discretisation error as state (firing_clock ``direction_error_*``, direction
``error_state``), seeds 100-149 of the scenario walk unless said (mean NEES filtered -> smoothed; dof 6
whole, 3 a block; RMSE position m, attitude deg):

| model | whole | attitude | position RMSE | attitude RMSE |
|---|---|---|---|---|
| shipped (white 30 deg, walk 0.8, cell 1 deg) | 5.57 -> 7.09 | 2.42 -> 4.11 | 0.0533 -> 0.0355 | 7.83 -> 7.28 |
| error state, none coupling, white 2 deg, walk 0.57, cell (the shipped recording, one run) | 11.96 -> 13.82 | - | 0.0515 -> 0.0362 | 11.43 -> 11.29 |
| error state, none coupling, white 2 deg, walk 0.57, no cell (4 seeds) | 17.48 -> 19.88 | 14.44 -> 16.31 | 0.0574 -> 0.0456 | 16.60 -> 13.98 |
| error state, direction coupling, white 2 deg, walk 0.57, cell (4 seeds) | 19.67 -> 34.91 | 12.27 -> 27.87 | 0.1096 -> 0.0676 | 12.72 -> 11.51 |
| the same, direction_position coupling (4 seeds; seed 102 diverges, 1.5 m) | 287.8 -> 414.3 | 138.4 -> 254.9 | 0.4384 -> 0.4211 | 15.62 -> 15.69 |
| error state, none coupling, added to the shipped model (4 seeds) | 5.28 -> 6.25 | 2.31 -> 2.93 | 0.0502 -> 0.0389 | 9.58 -> 8.69 |
| the same, 50 seeds | 5.67 -> 6.28 | 2.50 -> 3.28 | 0.0535 -> 0.0356 | 9.65 -> 8.72 |

Commands: E = ``--set process.direction_error_sd_deg=10.2 --set process.direction_error_tau_s=133 --set
model.error_state=true`` (sd: the receivers' RMS discretisation per axis; tau = 2 sd^2 over the direction's
variance rate from the walk, 0.57^2 deg^2 + (5 mm / 1.8 m)^2 per 0.225 s firing; 4 slots, the colours),
then ``--seeds 4 --jobs 2`` (or 50) with: own sd rows ``E --set model.sd_deg=2.0 --set
process.attitude_sd_deg=0.57`` and ``--set process.direction_error_coupling=none | direction |
direction_position``, ``--set model.cell=false`` for no cell; the last row ``E --set
process.direction_error_coupling=none`` (the shipped white sd, walk and cell kept). The slot reset did
not fire on the shipped recording (a new cell of a slot's colour within 300 s is rare).

Over walks (``--vary-trajectory``: the walk drawn with each seed, as experiments/smoother_seeds.py now does;
the shipped model unless said):

| model, seeds | whole | attitude | position RMSE | attitude RMSE |
|---|---|---|---|---|
| shipped, 100-149 (the study's runs) | 6.05 -> 6.90 | 3.03 -> 3.99 | 0.0514 -> 0.0344 | 7.83 -> 6.28 |
| shipped, 200-249 | 6.61 -> 8.15 | 3.60 -> 5.20 | 0.0514 -> 0.0347 | 7.83 -> 6.41 |
| shipped, 500-549 | 6.30 -> 7.33 | 3.32 -> 4.41 | 0.0510 -> 0.0344 | 7.92 -> 6.29 |
| ``--set model.sd_deg=40``, 500-549 | 6.09 -> 6.95 | 3.11 -> 4.03 | 0.0511 -> 0.0345 | 7.86 -> 6.00 |
| ultrasonic_3d_iekf.yaml (position only), 100-149 | 3.44 -> 3.40 | - | 0.0559 -> 0.0379 | - |
| shipped, 500-505 | 6.04 -> 7.38 | 3.23 -> 4.61 | 0.0504 -> 0.0334 | 8.05 -> 6.70 |
| error state E2 (below), 500-505; seed 502 diverges (attitude 137 deg) | 454.8 -> 926.0 | 452.0 -> 923.3 | 0.0588 -> 0.0366 | 30.23 -> 28.65 |

E2 = ``--set process.direction_error_sd_deg=9.5 --set process.direction_error_tau_s=30 --set
model.error_state=true --set process.direction_error_coupling=none --set model.sd_deg=3.7 --set
process.attitude_sd_deg=0.57`` (the fit 0.87 exp(-k/33) + 0.13 at k = 0 of ``--acf``'s autocorrelation:
correlated sd 9.5 deg, tau 30 s, white 3.7 deg; the paper's walk); without seed 502 its attitude NEES is
3.8-15.8 filtered: over-confident, as the error state with its own sd in the first table.

The smoothed attitude is over-confident on every set, the filtered one and the position are not; the
smoothed / filtered attitude NEES is ~1.3 whatever the white sd. ``--acf --seeds 20 --first-seed 300``: the
directions' discretisation error over walks not scored (no echoes), its autocorrelation and the white-noise
equivalents (:func:`window_factor`) for a filter's and a smoother's window: at every window the smoother's is
1.4-1.8 times the filter's variance, the cause.

The last row of the first table makes the smoother consistent (50 seeds: whole 6.28 inside 5.04-6.96, attitude 3.28 inside
2.32-3.68, 0.957 of the samples inside their 95% interval) by doubling the error's variance (white and state
both stand for the discretisation) and costs attitude accuracy (+1.8 deg filtered, +1.4 smoothed); the models that give the error its own sd only are
over-confident: the discretisation is a deterministic function of the state (z = the normal closest to u),
not noise independent of it, and a Gaussian error state either ignores that its increments are minus the
direction's (none: the filter then reads the constant normal as a still attitude) or, coupled, carries
little information besides its prior. Not shipped.
"""
from __future__ import annotations

import numpy as np

from fusion import quaternion as quat
from fusion.metrics import Truth

__all__ = ["block_nees"]


def block_nees(estimates, truth: Truth, layout) -> dict:
    """Mean NEES of the position block (3 dof) and of the attitude (3 dof) over ``estimates``."""
    ip = layout["p"]
    iq = layout["q"] if "q" in layout else None
    pos, att = [], []
    for est in estimates:
        tv = truth.at(est.t)
        if tv is None:
            continue
        x, P = est.belief.x, est.belief.cov
        e = x[ip] - np.array([tv["px"], tv["py"], tv["pz"]])
        pos.append(float(e @ np.linalg.solve(P[ip, ip], e)))
        if iq is None:
            continue
        q = x[iq] / np.linalg.norm(x[iq])
        qt = np.array([tv["qw"], tv["qx"], tv["qy"], tv["qz"]])
        d = quat.multiply(quat.conjugate(qt), q)
        d = -d if d[0] < 0 else d
        w, a, b, c = q[0], -q[1], -q[2], -q[3]
        T = 2.0 * np.array([[a, w, -c, b], [b, c, w, -a], [c, -b, a, w]])
        ea = 2.0 * d[1:]
        att.append(float(ea @ np.linalg.solve(T @ P[iq, iq] @ T.T, ea)))
    return {"p": float(np.mean(pos)), "attitude": float(np.mean(att)) if att else float("nan")}


def direction_errors(text: str, beacons: dict) -> dict:
    """Per beacon, the discretisation errors ``n_r - u`` (k, 3) (body frame) of its pulses in a recording's
    ``text``, in time order: n_r the normal of the receiver reported, u the true direction of the beacon
    (truth interpolated to the arrival). Echoes (a random direction) have no place in the correlation of the
    discretisation: simulate without them (``echo_prob: 0``)."""
    from fusion import quaternion as quat
    from fusion_plugins.measurement.direction import receiver_normals

    normals = receiver_normals("truncated_icosahedron")
    tr, us = [], []
    for ln in text.splitlines():
        if ln.startswith("#"):
            continue
        f = ln.split(",")
        if f[1] == "truth":
            tr.append([float(v) for v in [f[0]] + f[2:12]])
        elif f[1] == "us":
            us.append((float(f[0]), f[2], int(f[4])))
    tr = np.array(tr)
    out = {}
    for b, pos in beacons.items():
        e = []
        for t, name, r in us:
            if name != b:
                continue
            i = min(max(int(np.searchsorted(tr[:, 0], t)), 1), len(tr) - 1)
            a = (t - tr[i - 1, 0]) / (tr[i, 0] - tr[i - 1, 0])
            x = (1 - a) * tr[i - 1] + a * tr[i]
            q = x[7:11] / np.linalg.norm(x[7:11])
            d = np.asarray(pos, float) - x[1:4]
            e.append(normals[r - 1] - quat.rotate(quat.conjugate(q), d / np.linalg.norm(d)))
        out[b] = np.array(e)
    return out


def correlation(seeds, lags: int = 300) -> tuple[float, np.ndarray]:
    """RMS per tangent axis (rad) of the directions' discretisation error and its autocorrelation rho(k),
    k = 0..lags pulses of one beacon, over random walks of scenarios/ultrasonic_3d_walk.yaml drawn with
    ``seeds`` (the walk too, no echoes): what the array's geometry and the paper's walk make of it."""
    import ultrasonic_3d_cases as uc
    from fusion.simulate import simulate

    num, cnt = np.zeros(lags + 1), np.zeros(lags + 1)
    for seed in seeds:
        sc = uc.scenario("ultrasonic_3d_walk", seed, us__echo_prob=0.0)
        for e in direction_errors(simulate(sc, seed=seed), sc.beacons).values():
            for k in range(min(lags + 1, len(e))):
                num[k] += np.sum(e[:len(e) - k] * e[k:])
                cnt[k] += len(e) - k
    c = num / np.maximum(cnt, 1)
    return float(np.sqrt(c[0] / 2.0)), c / c[0]


def window_factor(rho: np.ndarray, m: float, two_sided: bool) -> float:
    """g: the variance of an error of autocorrelation ``rho`` averaged with weights exp(-|k| / m) (k >= 0 for
    a filter, all k for a smoother) over the variance of the same average of a white error of the same
    variance. A white noise of variance sd^2 g stands for the correlated one of variance sd^2 in that
    average, and only in that one."""
    K = len(rho) - 1
    k = np.arange(-K if two_sided else 0, K + 1)
    w = np.exp(-np.abs(k) / m)
    lag = np.minimum(np.abs(k[:, None] - k[None, :]), K)
    return float(w @ rho[lag] @ w / (w @ w))


def variant(config, sets: list[str], out) -> str:
    """Write ``config`` with overrides ``process.KEY=VALUE`` / ``model.KEY=VALUE`` (the us sensor's model) /
    ``sd.BLOCK=VALUE`` (initial sd) (YAML values; ``DEL`` removes the key) to the file ``out`` (its recording
    path made absolute); returns the path."""
    from pathlib import Path

    import yaml

    d = yaml.safe_load(Path(config).read_text())
    for kv in sets:
        key, value = kv.split("=", 1)
        sec, name = key.split(".", 1)
        tgt = {"process": d["process"], "model": d["sensors"]["us"]["model"], "sd": d["initial"]["sd"]}[sec]
        v = yaml.safe_load(value)
        if v == "DEL":
            tgt.pop(name, None)
        else:
            tgt[name] = v
    if "direction_error_sd_deg" in d["process"]:
        for b in d["beacons"]:
            d["initial"]["sd"].setdefault(f"dir_err_{b}", float(np.deg2rad(d["process"]["direction_error_sd_deg"])))
    if "recording" in d:
        d["recording"] = str((Path(config).parent / d["recording"]).resolve())
    path = Path(out)
    path.write_text(yaml.safe_dump(d, sort_keys=False))
    return str(path)


def run_seed(config, seed: int, vary_trajectory: bool, tmp) -> dict:
    """One seed of ``config`` on the walk scenario: the summary's filtered and smoothed scores and the block
    NEES of both. ``vary_trajectory``: the walk itself is drawn with the seed too (experiments/
    ultrasonic_3d_cases.scenario), not only the noise (the scenario's fixed walk, as smoother_seeds.py)."""
    from pathlib import Path

    from fusion import pipeline
    from fusion.config import load_system
    from fusion.simulate import simulate
    from fusion.simulate.engine import simulate_file
    from fusion.smoothing import run_smoothed

    root = Path(__file__).resolve().parents[1]
    system = load_system(config)
    if vary_trajectory:
        import ultrasonic_3d_cases as uc
        text = simulate(uc.scenario("ultrasonic_3d_walk", seed), seed=seed)
    else:
        text = simulate_file(str(root / "scenarios" / "ultrasonic_3d_walk.yaml"), seed=seed)
    log = Path(tmp) / f"walk_{seed}.log"
    log.write_text(text)
    truth = Truth.from_recording(log)
    fwd, smc = pipeline.Collect(), pipeline.Collect()
    s = run_smoothed(system, str(log), [smc], forward_sinks=[fwd]).summary
    bf, bs = block_nees(fwd.estimates, truth, system.layout), block_nees(smc.estimates, truth, system.layout)
    sm = s["smoothed"]
    return {"p_f": bf["p"], "p_s": bs["p"], "att_f": bf["attitude"], "att_s": bs["attitude"],
            "rmse_f": s["errors"]["position_rmse_m"], "rmse_s": sm["errors"]["position_rmse_m"],
            "att_rmse_f": s["errors"].get("attitude_rmse_deg", float("nan")),
            "att_rmse_s": sm["errors"].get("attitude_rmse_deg", float("nan")),
            "nees_f": s["consistency"]["nees_mean"], "nees_s": sm["consistency"]["nees_mean"],
            "in95_f": s["consistency"]["nees_in_95_fraction"], "in95_s": sm["consistency"]["nees_in_95_fraction"],
            "dof": s["consistency"]["nees_dof"]}


def _one(args):
    config, seed, vary = args
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        return run_seed(config, seed, vary, d)


def main(argv=None) -> int:
    """``python experiments/pose_blocks.py [--config C] [--seeds 50] [--first-seed 100] [--vary-trajectory]
    [--jobs 4]``: mean over the seeds of the whole and per-block NEES and the RMSEs, filtered and smoothed."""
    import argparse
    import sys
    from concurrent.futures import ProcessPoolExecutor
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    sys.path.insert(0, str(root / "experiments"))
    ap = argparse.ArgumentParser(description="per-block NEES of the paper-003 pose filter over seeds")
    ap.add_argument("--config", default=str(root / "configs" / "ultrasonic_3d_pose.yaml"))
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--vary-trajectory", action="store_true", help="a new walk for every seed too")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--verbose", action="store_true", help="one line a seed")
    ap.add_argument("--set", action="append", default=[], metavar="SEC.KEY=VALUE",
                    help="override process.KEY, model.KEY (the us model) or sd.BLOCK (initial sd); repeatable")
    ap.add_argument("--acf", action="store_true", help="instead: the directions' discretisation error, its "
                    "autocorrelation over walks of --seeds from --first-seed (use seeds not scored) and the "
                    "white-noise equivalents for a filter's and a smoother's window")
    args = ap.parse_args(argv)
    if args.acf:
        sd, rho = correlation(range(args.first_seed, args.first_seed + args.seeds))
        print(f"discretisation error: {np.degrees(sd):.2f} deg RMS per tangent axis ({args.seeds} walks from seed "
              f"{args.first_seed}, no echoes); autocorrelation at k pulses of a beacon (0.9 s each):")
        print("  " + ", ".join(f"{k}: {rho[k]:.2f}" for k in (1, 2, 5, 10, 20, 50, 100, 150, 200)))
        print(f"  integral time {0.5 + rho[1:].sum():.1f} pulses")
        print("window m (pulses) | filter g (white sd, deg) | smoother g (white sd, deg) | smoother / filter")
        for m in (2, 4, 6, 8, 10, 15, 20, 30, 60):
            gf, gs = window_factor(rho, m, False), window_factor(rho, m, True)
            print(f"  {m:3d} | {gf:6.2f} ({np.degrees(sd) * gf ** 0.5:5.1f}) | {gs:6.2f} "
                  f"({np.degrees(sd) * gs ** 0.5:5.1f}) | {gs / gf:.2f}")
        return 0
    if args.set:
        import os
        import tempfile
        args.config = variant(args.config, args.set, os.path.join(tempfile.gettempdir(),
                                                                  f"pose_blocks_{os.getpid()}.yaml"))
    todo = [(args.config, s, args.vary_trajectory) for s in range(args.first_seed, args.first_seed + args.seeds)]
    try:
        if args.jobs > 1:
            with ProcessPoolExecutor(args.jobs) as ex:
                rows = list(ex.map(_one, todo))
        else:
            rows = [_one(t) for t in todo]
    finally:
        if args.set:
            Path(args.config).unlink()
    if args.verbose:
        for (_, seed, _), r in zip(todo, rows):
            print(f"  seed {seed}: NEES {r['nees_f']:.2f} -> {r['nees_s']:.2f}, attitude {r['att_f']:.2f} -> {r['att_s']:.2f}, "
                  f"RMSE {r['rmse_f']:.4f} -> {r['rmse_s']:.4f} m, {r['att_rmse_f']:.2f} -> {r['att_rmse_s']:.2f} deg")
    m = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
    print(f"{Path(args.config).name} {' '.join(args.set)}: {len(rows)} seeds from {args.first_seed}, "
          f"{'walk drawn per seed' if args.vary_trajectory else 'the scenario walk'}")
    print(f"  NEES (dof {m['dof']:.0f}): filtered {m['nees_f']:.2f} (in 95% {m['in95_f']:.3f}), "
          f"smoothed {m['nees_s']:.2f} (in 95% {m['in95_s']:.3f})")
    print(f"  position NEES (3): {m['p_f']:.2f} -> {m['p_s']:.2f}; attitude NEES (3): {m['att_f']:.2f} -> {m['att_s']:.2f}")
    print(f"  position RMSE (m): {m['rmse_f']:.4f} -> {m['rmse_s']:.4f}; attitude RMSE (deg): "
          f"{m['att_rmse_f']:.2f} -> {m['att_rmse_s']:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
