"""Filtered against smoothed on configs/abps_ins.yaml (issue 17): the section "Filtered against smoothed" of
docs/results/abps_ins.md and its figure, used by experiments/abps_results.py; alone (prints the rows):

    python experiments/abps_smoothed.py --seeds 20

One ``fusion.smoothing.run_smoothed`` run gives both: its ``forward_sinks`` get the filter's estimates, its
sinks the Rauch-Tung-Striebel smoothed ones (the same times), scored against the same truth by
:func:`error_rows` (the 15-dof error [p v attitude ba bw], attitude as a body-frame rotation). Seeds:
scenarios/abps_mine.yaml re-simulated with seeds 100.. (same route, new noise and outliers), and the same
route on a flat floor (every waypoint at the first one's height, so the config's known receiver height
of -0.75 m is the true one): the control that separates the smoother from the height assumption.
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import re  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from fusion import pipeline  # noqa: E402
from fusion import quaternion as quat  # noqa: E402
from fusion.config import load_system  # noqa: E402
from fusion.consistency import chi2_interval  # noqa: E402
from fusion.metrics import Truth  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "abps_ins.yaml"
SCENARIO = ROOT / "scenarios" / "abps_mine.yaml"
FIG = ROOT / "docs" / "results" / "abps_ins"
BLOCKS = (("p", 3), ("v", 3), ("attitude", 3), ("ba", 3), ("bw", 3))
_VEC = ("px", "py", "pz", "vx", "vy", "vz")
_BIAS = ("bax", "bay", "baz", "bwx", "bwy", "bwz")


def error_rows(estimates, truth: Truth) -> dict:
    """Errors of ``estimates`` (16-state INS beliefs) against ``truth``: ``t`` (k,), ``E`` (k, 15) = estimate
    - truth of [p (m) v (m/s) attitude (rad, body frame) ba (m/s^2) bw (rad/s)] (appended Gauss-Markov
    blocks have no truth and are left out), ``SD`` (k, 15), ``C``
    (k, 15, 15) the covariance of that error, ``nees`` (k,), ``blocks`` {name: (k,) NEES of the block},
    ``nis`` (k,) and ``X`` (k, 16) the estimates."""
    rows = []
    for est in estimates:
        tv = truth.at(est.t)
        if tv is None:
            continue
        x, P = est.belief.x, est.belief.cov
        qt = np.array([tv["qw"], tv["qx"], tv["qy"], tv["qz"]])
        q = x[6:10] / np.linalg.norm(x[6:10])
        d = quat.multiply(quat.conjugate(qt), q)       # q_true^-1 (x) q_est: body-frame error rotation
        d = -d if d[0] < 0 else d
        w, a, b, c = q[0], -q[1], -q[2], -q[3]           # rows of L(q_est^-1), doubled: d theta = 2 vec(q^-1 dq)
        T = np.zeros((15, 16))
        T[0:6, 0:6] = np.eye(6)
        T[6:9, 6:10] = 2.0 * np.array([[a, w, -c, b], [b, c, w, -a], [c, -b, a, w]])
        T[9:15, 10:16] = np.eye(6)
        err = np.concatenate([x[0:6] - [tv[n] for n in _VEC], 2.0 * d[1:], x[10:16] - [tv[n] for n in _BIAS]])
        upd = getattr(est, "update", None)
        rows.append((est.t, err, T @ P[:16, :16] @ T.T, upd.nis if upd else np.nan, x.copy()))
    E = np.array([r[1] for r in rows])
    C = np.array([r[2] for r in rows])
    nees = np.array([float(e @ np.linalg.solve(c, e)) for e, c in zip(E, C)])
    blocks, i = {}, 0
    for name, k in BLOCKS:
        blocks[name] = np.array([float(e[i:i + k] @ np.linalg.solve(c[i:i + k, i:i + k], e[i:i + k]))
                                 for e, c in zip(E, C)])
        i += k
    return {"t": np.array([r[0] for r in rows]), "E": E, "SD": np.sqrt(np.einsum("kii->ki", C)), "C": C,
            "nees": nees, "blocks": blocks, "nis": np.array([r[3] for r in rows]), "X": np.array([r[4] for r in rows])}


def brief(r: dict) -> dict:
    """Scores of :func:`error_rows`: horizontal, vertical, velocity and attitude RMSE, NEES and its 95%
    fraction, block NEES, and each element's mean squared error over its variance (``el``)."""
    E, nees = r["E"], r["nees"]
    lo, hi = chi2_interval(15)
    rms = lambda a: float(np.sqrt(np.mean(a ** 2)))  # noqa: E731
    h = np.hypot(E[:, 0], E[:, 1])
    return {"h_rmse": rms(h), "h_max": float(h.max()), "z_rmse": rms(E[:, 2]),
            "v_rmse": rms(np.linalg.norm(E[:, 3:6], axis=1)),
            "att_rmse": rms(np.degrees(np.linalg.norm(E[:, 6:9], axis=1))),
            "nees_mean": float(nees.mean()), "nees_in95": float(np.mean((nees >= lo) & (nees <= hi))),
            "block_nees": {k: float(v.mean()) for k, v in r["blocks"].items()},
            "el": (E ** 2 / r["SD"] ** 2).mean(axis=0)}


def both(system, source, truth: Truth) -> tuple[dict, dict, dict]:
    """(filtered rows, smoothed rows, summary) of one smoothed run of ``system`` over ``source``."""
    from fusion.smoothing import run_smoothed

    fwd, sm = pipeline.Collect(), pipeline.Collect()
    res = run_smoothed(system, source, [sm], forward_sinks=[fwd])
    return error_rows(fwd.estimates, truth), error_rows(sm.estimates, truth), res.summary


def flat_scenario(tmp: Path) -> Path:
    """scenarios/abps_mine.yaml with every waypoint at -0.35 m (the IMU; the receiver 0.4 m above it is then
    at the config's -0.75 m up to the lever arm's tilt): the known-height assumption holds."""
    text = SCENARIO.read_text()
    head, tail = text.split("waypoints:", 1)
    tail = re.sub(r"(\[\s*-?[\d.]+,\s*-?[\d.]+,\s*)-0\.\d+\]", r"\1-0.35]", tail)
    out = tmp / "abps_mine_flat.yaml"
    out.write_text(head + "waypoints:" + tail)
    return out


def seed_study(seeds: int, first: int = 100, progress: bool = True) -> list[dict]:
    """Filtered and smoothed scores over ``seeds`` seeds on the route as shipped and on a flat floor."""
    from fusion.simulate import simulate_file

    out = []
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for label, scen in (("abps_mine.yaml (floor dips 0.18 m)", SCENARIO), ("the same route, flat floor", flat_scenario(tmp))):
            per = []
            for s in range(first, first + seeds):
                log = tmp / f"run_{s}.log"
                log.write_text(simulate_file(str(scen), seed=s))
                f, sm, _ = both(load_system(CONFIG), str(log), Truth.from_recording(log))
                per.append((brief(f), brief(sm)))
                if progress:
                    print(f"  {label} seed {s}: horizontal {per[-1][0]['h_rmse']:.4f} -> {per[-1][1]['h_rmse']:.4f} m, "
                          f"NEES {per[-1][0]['nees_mean']:.1f} -> {per[-1][1]['nees_mean']:.1f}", flush=True)
            out.append({"label": label, "seeds": f"{first}-{first + seeds - 1}", "per": per})
    return out


def figure(f: dict, sm: dict) -> None:
    """docs/results/abps_ins/smoothed.png: px, py, pz errors, filtered and smoothed, with their 3-sigma bounds."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    FIG.mkdir(parents=True, exist_ok=True)
    fig = Figure(figsize=(11, 8), layout="constrained")
    FigureCanvasAgg(fig)
    for k, name in enumerate(("px", "py", "pz")):
        ax = fig.add_subplot(3, 1, k + 1)
        for r, col, lab in ((f, "C0", "filtered"), (sm, "C3", "smoothed")):
            ax.fill_between(r["t"], -3 * r["SD"][:, k], 3 * r["SD"][:, k], color=col, alpha=0.15, lw=0)
            ax.plot(r["t"], r["E"][:, k], col, lw=0.8, label=f"{lab} error (band: its 3 sigma)")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylabel(f"{name} error (m)")
        lim = np.percentile(np.abs(np.r_[3 * f["SD"][:, k], f["E"][:, k]]), 98) * 1.3
        ax.set_ylim(-lim, lim)
        if k == 0:
            ax.legend(loc="upper right", fontsize=8, ncol=2)
            ax.set_title("Filtered against smoothed (RTS) position errors, recordings/abps_mine.log")
    ax.set_xlabel("t (s)")
    fig.savefig(FIG / "smoothed.png", dpi=100)


def section(head: tuple[dict, dict], study: list[dict]) -> str:
    """The markdown section (the headline recording's two rows, then the seeds)."""
    f, sm = head
    L = ["## Filtered against smoothed (issue 17)", "",
         "`fusion run configs/abps_ins.yaml --smooth` runs the SR-UKF forward and its square-root Rauch-Tung-Striebel",
         "smoother backward (docs/smoothing.md); both scored as above on every estimate of the shipped recording:", "",
         "| estimate | horizontal RMSE (max) m | vertical RMSE m | velocity RMSE m/s | attitude RMSE deg | NEES mean "
         "(in 95%) | NEES p | v | attitude | ba | bw |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for label, r in (("filtered (SR-UKF)", f), ("smoothed (RTS)", sm)):
        b = r["block_nees"]
        L.append(f"| {label} | {r['h_rmse']:.3f} ({r['h_max']:.3f}) | {r['z_rmse']:.3f} | {r['v_rmse']:.3f} | "
                 f"{r['att_rmse']:.2f} | {r['nees_mean']:.1f} ({100 * r['nees_in95']:.0f}%) | "
                 + " | ".join(f"{b[k]:.2f}" for k, _ in BLOCKS) + " |")
    L += ["", "Over seeds (each seed re-simulates the route: new range noise, outliers and IMU noise; mean over seeds of",
          "each run's mean; reduction = 1 - smoothed / filtered horizontal RMSE):", "",
          "| scenario | seeds | horizontal RMSE filtered m | smoothed m | reduction mean (5th pct) | smoothed < filtered | "
          "NEES filtered | smoothed | p block f / s | v block f / s | pz: err^2/var f / s |",
          "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for row in study:
        per = row["per"]
        fh = np.array([a["h_rmse"] for a, _ in per])
        sh = np.array([b["h_rmse"] for _, b in per])
        red = 1.0 - sh / fh
        m = lambda key, i: float(np.mean([p[i][key] for p in per]))  # noqa: E731
        blk = lambda name, i: float(np.mean([p[i]["block_nees"][name] for p in per]))  # noqa: E731
        pz = lambda i: float(np.mean([p[i]["el"][2] for p in per]))  # noqa: E731
        L.append(f"| {row['label']} | {row['seeds']} | {fh.mean():.4f} +- {fh.std(ddof=1):.4f} | "
                 f"{sh.mean():.4f} +- {sh.std(ddof=1):.4f} | {100 * red.mean():.1f}% ({100 * np.percentile(red, 5):.1f}%) | "
                 f"{int((sh < fh).sum())}/{len(per)} | {m('nees_mean', 0):.1f} | {m('nees_mean', 1):.1f} | "
                 f"{blk('p', 0):.2f} / {blk('p', 1):.2f} | {blk('v', 0):.2f} / {blk('v', 1):.2f} | {pz(0):.2f} / {pz(1):.2f} |")
    per = study[0]["per"]
    red = np.array([1.0 - b["h_rmse"] / a["h_rmse"] for a, b in per])
    L += ["", "![filtered against smoothed position errors](abps_ins/smoothed.png)", "",
          f"On the shipped route the smoothed horizontal RMSE is {100 * red.mean():.0f}% below the filtered one on "
          f"average, at least {100 * red.min():.0f}% on every one of the {len(per)} seeds (issue 17 asks 25%).",
          "The height: the 2-D fix takes the receiver height as known (-0.75 m) while the floor dips, so the fix's z",
          "is off by up to 0.13 m, slowly, along the route. Until issue 17 the config gave each fix that error as",
          "independent noise (`z_sd: 0.3`, three times its size, so that the *filter* stayed consistent); the smoother,",
          "averaging the fixes on both sides of each time, was not (over 50 seeds: smoothed NEES 16.8 on 15 dof, pz",
          "2.9 where 1 is consistent; docs/results/smoothing.md of that commit). A white-noise R cannot be right for",
          "both the filter and the smoother of a slowly changing error, so the error is now a state of the model:",
          "`hz`, first-order Gauss-Markov (sd 0.1 m, tau 10 s, from the floor's dip and the vehicle's pace: the",
          "config's comment), added to the fix's z (`offset_block: hz`), with `z_sd: 0.05` for what each fix adds",
          "afresh. The flat floor (the assumption true, nothing else changed) is the control.", ""]
    return "\n".join(L)


def study_and_section(seeds: int) -> str:
    """Everything this module adds to the page (and the figure)."""
    system = load_system(CONFIG)
    truth = Truth.from_recording(system.recording)
    f, sm, _ = both(system, system.recording, truth)
    figure(f, sm)
    return section((brief(f), brief(sm)), seed_study(seeds))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    args = ap.parse_args(argv)
    print(study_and_section(args.seeds))


if __name__ == "__main__":
    main()
