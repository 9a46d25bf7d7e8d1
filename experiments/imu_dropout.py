"""The IMU alone silent while the other sensors go on: errors against the gap's length, over many seeds;
writes docs/results/imu_dropout.md and its figure.

    python experiments/imu_dropout.py                  # 8 seeds x 3 gaps each, ~25 min on 1 core
    python experiments/imu_dropout.py --seeds 3        # quicker
    python experiments/imu_dropout.py --shipped --json /tmp/before.json --root OLD_CHECKOUT   # shipped only

For each seed, ``fusion simulate`` writes the scenario's recording with that seed (same route, new noise),
and for each gap length the IMU lines of ``--per-seed`` windows, drawn at random in the moving part of the
route, are cut out one window at a time (the other sensors' lines and the truth kept). Each cut recording
is replayed by ``fusion run CONFIG --input ... --summary-json`` with the config's own filter (and the
paper 002 system with the UKF too), and its position RMSE, maximum error, NEES, resets and GPS refusals
are collected. ``--shipped``: the shipped recordings with five fixed windows, the table this page quotes
for the code before the hold model was changed (run it with that commit's package installed: it uses only
the command line).

Only the command line and the log format are used (no fusion import beyond the line cutting written
here), so the same script measures any version of the package.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import provenance  # noqa: E402  (experiments/, on the path: the page's provenance block)

#: The files the page is made from: their hashes go in its provenance block (experiments/provenance.py).
INPUTS = ("configs/abps_ins.yaml", "configs/imu_gps_mag_ekf.yaml", "recordings/abps_mine.log",
          "recordings/car_gps_mag.log", "scenarios/abps_mine.yaml", "scenarios/car_gps_mag.yaml")

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "results" / "imu_dropout.md"
FIG = ROOT / "docs" / "results" / "imu_dropout" / "rmse_vs_gap.png"
GAPS = (0.0, 1.0, 5.0, 10.0)                      # s
#: (label, config, scenario, shipped recording, filters, the moving part of the route (s) the windows fall in)
SYSTEMS = (
    ("abps_ins (srukf)", "configs/abps_ins.yaml", "scenarios/abps_mine.yaml", "recordings/abps_mine.log", (None,),
     (15.0, 130.0)),
    ("imu_gps_mag_ekf (ekf)", "configs/imu_gps_mag_ekf.yaml", "scenarios/car_gps_mag.yaml",
     "recordings/car_gps_mag.log", (None,), (50.0, 290.0)),
    ("imu_gps_mag_ekf (ukf)", "configs/imu_gps_mag_ekf.yaml", "scenarios/car_gps_mag.yaml",
     "recordings/car_gps_mag.log", ("ukf",), (50.0, 290.0)),
)
SHIPPED_STARTS = {"configs/abps_ins.yaml": (20.0, 45.0, 70.0, 95.0, 120.0),
                  "configs/imu_gps_mag_ekf.yaml": (60.0, 110.0, 160.0, 210.0, 260.0)}


def cut_imu(lines: list[str], start: float, length: float) -> list[str]:
    """The recording without its IMU lines in [start, start + length) s."""
    if length <= 0.0:
        return lines
    out = []
    for ln in lines:
        if not ln.startswith("#"):
            head = ln.split(",", 2)
            if len(head) > 1 and head[1] == "imu" and start <= float(head[0]) < start + length:
                continue
        out.append(ln)
    return out


def replay(config: str, lines: list[str], filt: str | None, work: Path) -> dict:
    log, summary = work / "in.log", work / "s.json"
    log.write_text("\n".join(lines) + "\n")
    cmd = ["fusion", "run", str(ROOT / config), "--input", str(log), "-q", "--no-progress",
           "--summary-json", str(summary), "--force"] + (["--filter", filt] if filt else [])
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if not summary.exists():
        return {"exit": proc.returncode, "rmse": float("nan"), "max": float("nan"), "nees": float("nan"),
                "resets": 0, "rejected": 0}
    s = json.loads(summary.read_text())
    summary.unlink()
    err = s.get("errors") or {}
    nees = (s.get("consistency") or {}).get("nees_mean")
    nees = float("nan") if nees is None else nees
    rejected = sum(v.get("rejected", 0) for k, v in (s.get("sensors") or {}).items() if k != "imu")
    return {"exit": proc.returncode, "rmse": err.get("position_rmse_m", float("nan")),
            "max": err.get("position_max_m", float("nan")), "nees": nees,
            "resets": (s.get("health") or {}).get("resets", 0), "rejected": rejected}


def simulate(scenario: str, seed: int, work: Path) -> list[str]:
    path = work / f"sim_{seed}.log"
    subprocess.run(["fusion", "simulate", str(ROOT / scenario), "-o", str(path), "--seed", str(seed), "--force"],
                   check=True, capture_output=True, cwd=ROOT)
    lines = path.read_text().splitlines()
    path.unlink()
    return lines


def study(seeds: int, per_seed: int, work: Path) -> dict:
    rows: dict = {}
    for label, config, scenario, _, filters, (lo, hi) in SYSTEMS:
        rows[label] = {str(g): [] for g in GAPS}
        for seed in range(100, 100 + seeds):
            lines = simulate(scenario, seed, work)
            starts = np.random.default_rng(seed).uniform(lo, hi - max(GAPS), size=per_seed)
            base = replay(config, lines, filters[0], work)
            rows[label]["0.0"].append(base)
            for g in GAPS[1:]:
                for s0 in starts:
                    r = replay(config, cut_imu(lines, float(s0), g), filters[0], work)
                    r["base_rmse"], r["start"], r["seed"] = base["rmse"], float(s0), seed
                    rows[label][str(g)].append(r)
            print(f"{label} seed {seed}: done", file=sys.stderr, flush=True)
    return rows


def shipped(work: Path) -> dict:
    rows: dict = {}
    for label, config, _, recording, filters, _ in SYSTEMS:
        lines = (ROOT / recording).read_text().splitlines()
        rows[label] = {str(g): [dict(replay(config, cut_imu(lines, s0, g), filters[0], work), start=s0)
                                for s0 in SHIPPED_STARTS[config]] for g in (0.0, 1.0, 2.0, 5.0, 10.0)}
    return rows


def _fmt(v: float, digits: int = 3) -> str:
    return "nan" if not np.isfinite(v) else f"{v:.{digits}f}"


def page(rows: dict, ship: dict, before: dict | None, args, wall: float) -> str:
    out = ["# IMU dropouts: the IMU alone silent while the other sensors go on", "",
           f"Regenerate: `python experiments/imu_dropout.py --seeds {args.seeds} --per-seed {args.per_seed}"
           + (" --before BEFORE.json" if before else "") + "` "
           f"({platform.machine()}, Python {platform.python_version()}; {wall / 60:.1f} min)"
           + ("; the \"before\" rows: `python experiments/imu_dropout.py --shipped --json BEFORE.json --root OLD` "
              "with OLD a checkout of commit b218d91 and its package installed" if before else "")
           + ". Every number is a "
           "`fusion run CONFIG --input CUT.log` of a recording whose IMU lines in one window were cut out "
           "(the other sensors' lines and the truth kept).", "",
           "## The model", "",
           "During an input gap the INS holds the last sample for `hold_after` (1.5 sample periods), then "
           "coasts (attitude and velocity kept, `p += v e`), and the hold noise is the vehicle's own motion: "
           "its acceleration (`hold_accel_sd`), heading rate (`hold_yaw_rate_sd`) and roll and pitch rates "
           "(`hold_tilt_rate_sd`) as first-order Gauss-Markov processes of correlation time "
           "`hold_motion_tau`, whose integrals are the coast's velocity and attitude errors "
           "(plugins/process/ins_batch.py `add_hold_noise`). A gap during which other sensors report is "
           "cut into many predictions; each is told how long the sample has been held already "
           "(`fusion.api.HoldsInput`, `Ins.held(age)`), so it integrates the sample only over what is left "
           "of `hold_after` and adds the noise that accrued over its own stretch: the velocity and attitude "
           "variances of a gap are the same however it is cut (tests/models/test_ins_hold.py, to 1e-9).", "",
           "Before (commit b218d91) the hold noise was an input random walk restarted at every prediction: "
           "cut by a 6 Hz magnetometer into ~30 pieces, a 5 s gap got ~1/30 of the velocity and attitude sd "
           "its own model gave it, and every piece integrated the held sample over `hold_after` again. The "
           "paper 002 filter was then sure of an attitude it had lost: GPS and magnetometer refused for "
           "seconds, errors of 100 m and more, a reset. An isotropic attitude noise (tried on the way) let "
           "the magnetometer, the only attitude measurement during a gap, tilt the estimate: the EKF diverged "
           "(1e8 m) when the IMU came back; hence separate tilt and heading.", ""]
    out += ["## The shipped recordings, five fixed windows", "",
            "Position RMSE (m) over the whole run, one column per window start (s); gap 0 is the uncut run.", ""]
    for label in ship:
        starts = [r["start"] for r in next(iter(ship[label].values()))]
        out += [f"**{label}**", "", "| gap (s) | " + " | ".join(f"{s:g} s" for s in starts) + " | resets |",
                "|---:|" + "---:|" * len(starts) + "---:|"]
        for g, rs in ship[label].items():
            out.append(f"| {float(g):g} | " + " | ".join(_fmt(r["rmse"]) for r in rs) + f" | {sum(r['resets'] for r in rs)} |")
            if before and label in before and g in before[label]:
                b = before[label][g]
                out.append(f"| {float(g):g} before | " + " | ".join(_fmt(r["rmse"]) for r in b)
                           + f" | {sum(r['resets'] for r in b)} |")
        out.append("")
    out += ["## Over seeds", "",
            f"{args.seeds} seeds (100-{99 + args.seeds}: same route, new noise), {args.per_seed} windows a seed "
            "drawn in the moving part of the route. RMSE over the whole run; its ratio to the same seed's uncut "
            "run; NEES mean over the run (dof 15 for abps_ins, 21 for imu_gps_mag_ekf).", "",
            "| system | gap (s) | runs | RMSE median (m) | RMSE max (m) | ratio median | ratio max | max error, max (m) "
            "| NEES median | runs with a reset | not exit 0 |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for label, by_gap in rows.items():
        for g, rs in by_gap.items():
            rm = np.array([r["rmse"] for r in rs])
            ratio = np.array([r["rmse"] / r.get("base_rmse", r["rmse"]) for r in rs])
            out.append(f"| {label} | {float(g):g} | {len(rs)} | {_fmt(np.nanmedian(rm))} | {_fmt(np.nanmax(rm))} | "
                       f"{_fmt(np.nanmedian(ratio), 2)} | {_fmt(np.nanmax(ratio), 2)} | "
                       f"{_fmt(np.nanmax([r['max'] for r in rs]), 2)} | {_fmt(np.nanmedian([r['nees'] for r in rs]), 1)} | "
                       f"{sum(1 for r in rs if r['resets'])} | {sum(1 for r in rs if r['exit'] != 0)} |")
    out += ["", f"![RMSE against the gap](imu_dropout/{FIG.name})", "",
            "What a gap costs is what the vehicle did in it that no sensor saw: the ABPS vehicle has no heading "
            "sensor, so after a long gap in a U-turn its heading is learnt again from the fixes; the car's "
            "magnetometer holds the heading through the gap, and the GPS its position and velocity.", ""]
    return "\n".join(out)


def figure(rows: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    FIG.parent.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(1, len(rows), figsize=(4.2 * len(rows), 3.4))
    for ax, (label, by_gap) in zip(np.atleast_1d(axes), rows.items()):
        gaps = [float(g) for g in by_gap]
        med = [np.nanmedian([r["rmse"] for r in rs]) for rs in by_gap.values()]
        mx = [np.nanmax([r["rmse"] for r in rs]) for rs in by_gap.values()]
        ax.plot(gaps, med, "o-", label="median")
        ax.plot(gaps, mx, "s--", label="max")
        ax.set_xlabel("IMU gap (s)")
        ax.set_ylabel("position RMSE (m)")
        ax.set_title(label, fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(FIG, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--per-seed", type=int, default=3)
    ap.add_argument("--shipped", action="store_true", help="the shipped recordings only (no page)")
    ap.add_argument("--json", type=Path, help="write the numbers here too")
    ap.add_argument("--before", type=Path, help="a --shipped --json of the code before, quoted on the page")
    ap.add_argument("--from-json", type=Path, help="rewrite the page from the numbers of an earlier --json")
    ap.add_argument("--root", type=Path, help="the checkout whose configs and recordings are used (default: "
                    "this one; another commit's, with its package installed, for --shipped)")
    args = ap.parse_args(argv)
    if args.root is not None:
        global ROOT
        ROOT = args.root.resolve()
    t0 = time.perf_counter()
    if args.from_json:
        saved = json.loads(args.from_json.read_text())
        before = json.loads(args.before.read_text()) if args.before else None
        figure(saved["seeds"])
        provenance.write_page(OUT, page(saved["seeds"], saved["shipped"], before, args, saved.get("wall_s", 0.0)),
                              INPUTS)
        print(f"wrote {OUT.relative_to(ROOT)}")
        return 0
    with tempfile.TemporaryDirectory() as d:
        work = Path(d)
        ship = shipped(work)
        if args.shipped:
            if args.json:
                args.json.write_text(json.dumps(ship, indent=1))
            print(json.dumps({k: {g: [round(r["rmse"], 3) for r in v] for g, v in by.items()} for k, by in ship.items()}))
            return 0
        rows = study(args.seeds, args.per_seed, work)
    before = json.loads(args.before.read_text()) if args.before else None
    if args.json:
        args.json.write_text(json.dumps({"shipped": ship, "seeds": rows, "wall_s": time.perf_counter() - t0},
                                        indent=1))
    figure(rows)
    provenance.write_page(OUT, page(rows, ship, before, args, time.perf_counter() - t0), INPUTS)
    print(f"wrote {OUT.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
