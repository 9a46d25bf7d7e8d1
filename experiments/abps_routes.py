"""ABPS/INS (configs/abps_ins.yaml) on every ABPS scenario x seeds: the study behind the route table of
docs/results/abps_ins.md (issue 11). Used by experiments/abps_results.py; alone:

    python experiments/abps_routes.py                 # every scenario x 10 seeds, noise on and off (~5 min)
    python experiments/abps_routes.py --seeds 2 --scenario abps_l_drift

For each scenario the config is the shipped one with the site's own facts: its beacons, the receiver
height (IMU height from the first waypoint + the lever arm's -0.4 m) and the initial position and yaw of
the route's first leg. Nothing else changes between sites. Each (scenario, seed) is simulated with
``fusion simulate SCENARIO --seed N`` into a temporary folder and replayed; scores: horizontal RMSE and
max (every estimate), NEES (15 dof), the fix stage (every emitted fix against the true receiver position
at the fix's own time: RMSE and its 2-dof horizontal NEES), rejected fixes (gate), cycles without a fix,
the longest stretch without an accepted fix while the vehicle moves among the beacons.
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import copy  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

from fusion import quaternion as quat  # noqa: E402
from fusion import pipeline  # noqa: E402
from fusion.config import SystemSpec, wire  # noqa: E402
from fusion.metrics import Truth  # noqa: E402
from fusion.simulate import simulate_file  # noqa: E402
from fusion_plugins.solvers.ols_trilateration import pack_fix, unpack_fix  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "abps_ins.yaml"
SCENARIOS = ("abps_mine", "abps_room_eight", "abps_l_drift", "abps_long_legs", "abps_fast_l")
LEVER_Z = -0.4            # m: the receiver's lever arm z (configs/abps_ins.yaml model.lever_arm)


def _run(system, log):
    """One replay: its estimates, parse state and the recording's truth, and its summary."""
    kept = pipeline.Collect()
    result = pipeline.run(system, log, [kept])
    # the run's own copies of the components (the wired system is not modified by a run)
    return {"estimates": kept.estimates, "parsed": result.parsed, "truth": Truth.from_recording(log),
            "sensors": result.stats.scheduler.sensors}, result.summary


def site_config(scenario: Path) -> dict:
    """configs/abps_ins.yaml with the site of ``scenario``: beacons, receiver height, initial position/yaw."""
    data = yaml.safe_load(CONFIG.read_text())
    sc = yaml.safe_load(scenario.read_text())
    wps = [w["at"] if isinstance(w, dict) else w for w in sc["trajectory"]["waypoints"]]
    p0, p1 = np.array(wps[0], float), np.array(wps[1], float)
    yaw = math.atan2(p1[1] - p0[1], p1[0] - p0[0])
    data["beacons"] = {k: list(map(float, v)) for k, v in sc["beacons"].items()}
    init = data["initial"]["mean"]
    init["p"] = [float(p0[0]), float(p0[1]), float(p0[2])]
    init["q"] = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
    pre = data["sensors"]["abps"]["preprocessor"]
    if scenario.stem != "abps_mine":
        pre["z"] = float(p0[2]) + LEVER_Z
    data.pop("recording", None)
    return data


def fix_stage(fixes: list, truth: Truth, arm: np.ndarray) -> dict:
    """Every emitted fix against the true receiver position at the time its position is of (``fix_*``), and
    as the position model's first-order bridge reads it at its stamp t with the true state there,
    ``p + C_b^n r - v age`` (``stamp_*``: what the filter compares the fix with; the bridge's own error is
    the difference), with the fixes' mean and largest age (s)."""
    err, nees, stamp, ages = [], [], [], []
    for t, vals in fixes:
        pos, cov = unpack_fix(vals[:9])
        age = vals[9] if len(vals) > 9 else 0.0
        tv, tv_t = truth.at(t - age), truth.at(t)
        if tv is None or tv_t is None:
            continue
        q = np.array([tv["qw"], tv["qx"], tv["qy"], tv["qz"]])
        rec = np.array([tv["px"], tv["py"], tv["pz"]]) + quat.rotate(q, arm)
        e = pos[:2] - rec[:2]
        err.append(float(np.hypot(*e)))
        nees.append(float(e @ np.linalg.solve(cov[:2, :2], e)))
        q_t = np.array([tv_t["qw"], tv_t["qx"], tv_t["qy"], tv_t["qz"]])
        bridged = (np.array([tv_t["px"], tv_t["py"], tv_t["pz"]]) + quat.rotate(q_t, arm)
                   - age * np.array([tv_t["vx"], tv_t["vy"], tv_t["vz"]]))
        stamp.append(float(np.hypot(*(pos[:2] - bridged[:2]))))
        ages.append(float(age))
    err_a, stamp_a = np.array(err), np.array(stamp)
    return {"fix_rmse": float(np.sqrt(np.mean(err_a ** 2))) if err else math.nan,
            "fix_max": float(err_a.max()) if err else math.nan,
            "fix_nees": float(np.mean(nees)) if nees else math.nan, "fixes": len(err),
            "stamp_rmse": float(np.sqrt(np.mean(stamp_a ** 2))) if stamp else math.nan,
            "stamp_max": float(stamp_a.max()) if stamp else math.nan,
            "age_mean": float(np.mean(ages)) if ages else math.nan, "age_max": float(max(ages)) if ages else math.nan}


def scenario_path(scenario: str) -> Path:
    """scenarios/NAME.yaml, or scenarios/variants/NAME.yaml (variants without a shipped recording)."""
    path = ROOT / "scenarios" / f"{scenario}.yaml"
    return path if path.exists() else ROOT / "scenarios" / "variants" / f"{scenario}.yaml"


def one(scenario: str, seed: int, tmp: Path, noise: bool = True, changes: dict | None = None) -> dict:
    """Simulate ``scenario`` with ``seed`` and replay it through the site's config; the scores."""
    sc_path = scenario_path(scenario)
    log = tmp / f"{scenario}_{seed}_{'on' if noise else 'off'}.log"
    if not log.exists():
        log.write_text(simulate_file(str(sc_path), seed=seed, noise=noise))
    data = site_config(sc_path)
    for path, value in (changes or {}).items():
        node = data
        *head, last = path.split(".")
        for key in head:
            node = node[key]
        node[last] = value
    system = wire(SystemSpec.model_validate(copy.deepcopy(data)), None, CONFIG)
    fixes: list = []
    cls = type(system.sensors["abps"].preprocessor)  # a run works on copies: spy on the class
    feed, flush = cls.feed, cls.flush

    def _feed(self, msg):
        out = feed(self, msg)
        fixes.extend((m.t, pack_fix(m.value, m.cov) + ((m.age,) if m.age else ())) for m in out)  # typed Fix
        return out

    def _flush(self):
        out = flush(self)
        fixes.extend((m.t, pack_fix(m.value, m.cov) + ((m.age,) if m.age else ())) for m in out)  # typed Fix
        return out

    cls.feed, cls.flush = _feed, _flush
    try:
        c0 = time.process_time()
        result, s = _run(system, log)
        cpu = time.process_time() - c0
    finally:
        cls.feed, cls.flush = feed, flush
    pre = result["sensors"]["abps"].preprocessor
    truth = result["truth"]
    arm = np.array(data["sensors"]["abps"]["model"]["lever_arm"], float)
    fs = fix_stage(fixes, truth, arm)
    # longest time between accepted fixes after the alignment
    ups = [e.t for e in result["estimates"] if e.reason == "update" and e.update is not None and e.update.accepted]
    gap = float(np.max(np.diff(ups))) if len(ups) > 1 else math.inf
    ab = s["sensors"]["abps"]
    return {"scenario": scenario, "seed": seed, "noise": noise, "h_rmse": s["errors"]["position_rmse_m"],
            "h_max": s["errors"]["position_max_m"], "nees": s["consistency"]["nees_mean"],
            "rejected": ab["rejected"], "late": ab["late"], "no_fix": int(sum(pre.counters[r] for r in
                                                                              ("inconsistent", "ambiguous", "degenerate"))),
            "outliers_removed": pre.counters["outliers_removed"], "cycles": pre.counters["cycles"],
            "max_gap_s": gap, "resets": s["health"]["resets"], "cpu_s": cpu, **fs}


def study(seeds: int = 10, scenarios=SCENARIOS, noise_off: bool = True, progress: bool = True,
          changes: dict | None = None) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory() as tmpd:
        tmp = Path(tmpd)
        for sc in scenarios:
            for seed in range(1, seeds + 1):
                rows.append(one(sc, seed, tmp, changes=changes))
                if progress:
                    r = rows[-1]
                    print(f"{sc} seed {seed}: h {r['h_rmse']:.3f} ({r['h_max']:.2f}) fix {r['fix_rmse']:.3f} ({r['fix_max']:.2f}) "
                          f"nees {r['nees']:.1f} fix-nees {r['fix_nees']:.2f} rej {r['rejected']} "
                          f"nofix {r['no_fix']} gap {r['max_gap_s']:.1f}", flush=True)
                for f in tmp.glob("*.log"):
                    f.unlink()
            if noise_off:
                rows.append(one(sc, 0, tmp, noise=False, changes=changes))
                if progress:
                    r = rows[-1]
                    print(f"{sc} noise off: h {r['h_rmse']:.4f} ({r['h_max']:.3f}) fix {r['fix_rmse']:.4f}", flush=True)
    return rows


ROUTE_TEXT = {
    "abps_mine": "the shipped drift: 30 m, 7 beacons, four legs with stops, lane changes and two slow U-turns",
    "abps_room_eight": "three figure-eights in a 24 x 18 m room, 9 roof beacons 2.2 m above the receiver",
    "abps_l_drift": "an L-shaped drift (90 degree bend), 11 beacons, forward, back, forward",
    "abps_long_legs": "four long legs of a 50 m drift at 1.5 m/s, 10 beacons, U-turns and stops",
    "abps_fast_l": "the L-shaped drift driven hard: 13 beacons, 3 m/s, 3 m/s^2 braking into stops and U-turns",
}


def routes_section(rows: list[dict]) -> str:
    """The table over every ABPS scenario x seed (experiments/abps_routes.py), noise on and off."""
    L = []
    add = L.append
    add("## Routes it was not tuned on (issue 11)")
    add("")
    add("`python experiments/abps_routes.py` (run by this page's script): every ABPS scenario in `scenarios/`, each")
    add("simulated with seeds 1-10 (`fusion simulate SCENARIO --seed N`) and once with `--noise off`, replayed through")
    add("`configs/abps_ins.yaml` with only the site's own facts changed (its beacons, the receiver height, the initial")
    add("position and yaw of the first leg). Nothing was tuned on these recordings. Columns: horizontal RMSE and max")
    add("over every estimate; NEES (15 dof, expected 15); the fix stage (every emitted fix against the true receiver")
    add("position at the fix's time: RMSE, max, and its horizontal NEES, expected 2); fixes rejected by the filter's")
    add("gate; cycles without a fix (inconsistent, ambiguous or degenerate ranges); ranges dropped as outliers; the")
    add("longest time between accepted fixes; resets (the config's lock-out recovery, fusion/recovery.py).")
    add("")
    for sc in dict.fromkeys(r["scenario"] for r in rows):
        sel = [r for r in rows if r["scenario"] == sc and r["noise"]]
        off = [r for r in rows if r["scenario"] == sc and not r["noise"]]
        add(f"**`{sc}`**: {ROUTE_TEXT.get(sc, '')}.")
        add("")
        add("| seed | horizontal RMSE (max) m | NEES | fix RMSE (max) m | fix NEES | rejected | no fix | outliers dropped | longest gap s | resets |")
        add("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
        for r in sel + off:
            add(f"| {r['seed'] if r['noise'] else 'noise off'} | {r['h_rmse']:.3f} ({r['h_max']:.3f}) | {r['nees']:.1f} | "
                f"{r['fix_rmse']:.3f} ({r['fix_max']:.2f}) | {r['fix_nees']:.2f} | {r['rejected']} | {r['no_fix']} | "
                f"{r['outliers_removed']} | {r['max_gap_s']:.1f} | {r['resets']} |")
        add("")
    on = [r for r in rows if r["noise"]]
    off = [r for r in rows if not r["noise"]]
    add(f"Over all {len(on)} noisy runs: horizontal RMSE at most {max(r['h_rmse'] for r in on):.3f} m (target 0.10), "
        f"maximum at most {max(r['h_max'] for r in on):.3f} m (target 0.5), longest time without an accepted fix "
        f"{max(r['max_gap_s'] for r in on):.1f} s (target 2). Noise off: fix stage at most "
        f"{max(r['fix_rmse'] for r in off) * 100:.2f} cm RMS (target 1 cm), filter at most "
        f"{max(r['h_rmse'] for r in off) * 100:.2f} cm (target 2 cm).")
    add("")
    add("What the issue found and what changed (tests in `tests/models/test_abps_fix_stage.py`,")
    add("`tests/systems/test_abps_routes.py`):")
    add("")
    add("1. **Cycles from the firing schedule** (`plugins/solvers/firing_schedule.py`). A repeat of a beacon no longer")
    add("   closes a cycle: the emission time of each range (arrival - r / 343 m/s) modulo the firing period (learnt")
    add("   from the first 2 s of ranges, or `firing_period`) places it in its slot; the cycle boundary sits half a")
    add("   slot after the last slot before the largest gap of the slot phases, so it lies between slots even for")
    add("   beacons that come into range later. A cycle holding a beacon twice or spanning more than its period is split.")
    add("2. **Motion compensation from the filter**: the preprocessor reads the belief predicted to the cycle's mean")
    add("   range time (`fusion.api.ReadsBelief`, bound by the scheduler) and refers every range to that time with")
    add("   its velocity; every cycle is compensated, also right after a failed fix. Gauss-Newton starts from the")
    add("   belief's receiver position, in the basin of the filter's estimate.")
    add("3. **An honest fix covariance** (`plugins/solvers/range_fix.py`): range noise and geometry, the velocity's")
    add("   uncertainty (the filter's, plus 0.05 m/s of receiver velocity the state does not carry, plus 0.5 m/s^2")
    add("   within the cycle) as correlated range errors, the assumed height's, and the misfit factor max(1, chi2/dof).")
    add("   A cycle that is not compensated (no belief yet, or `motion_compensation: false`) takes the unknown motion")
    add("   (1 m/s sd, `prior_speed_sd`) the same way: on the shipped recording without compensation the trial config")
    add("   gave 0.58 m (3.1 m max) from overconfident fixes, this one 0.055 m (the variant row above).")
    add("   The fix NEES column above is the check (expected 2); the remaining excess comes from the few mirror")
    add("   fixes below.")
    add("4. **Consensus outlier rejection**: the whole cycle, then every subset with one range fewer, two fewer, scored by")
    add("   the chi-square of the whitened residuals; the consistent subset with the smallest chi-square is kept, and")
    add("   no fix is given when two consistent subsets disagree (ambiguous) or none is consistent.")
    add("5. **Lock-out recovery** (`recovery:` of the abps sensor, fusion/recovery.py): three fixes in a row over at")
    add("   least 1 s refused by far (NIS over twice the gate's threshold) re-set the position from the fix and")
    add("   inflate the sd of the velocity and attitude 10x. One cycle of self-consistent ranges 0.4 m off is refused")
    add("   by the gate and the fixes resume; three such cycles in a row used to lock the filter out for good (the")
    add("   third passes the gate at NIS 14.5, every later fix was refused while the error grew to 11 m); now the")
    add("   filter is reset 1.2 s later and the route error is back under the bar")
    add("   (`tests/systems/test_abps_routes.py::test_biased_cycles_do_not_lock_the_filter_out`). The resets column")
    add("   counts them on the routes above.")
    add("6. **End of input**: a measurement now integrates only the pending IMU samples up to its own time, so the")
    add("   last fix is applied at its time (no spurious `late`).")
    add("7. **The age of a fix** (tester5 #3, docs/results/abps_fix_age.md): a cycle closes at its last heard slot,")
    add("   not at a range of the next cycle, so the fix is applied no later than its last range; the acceleration")
    add("   over the age is in the compensation's and the bridge's covariance; the IMU's acceleration in the bridge")
    add("   and the compensation is opt-in. `abps_fast_l` (13 beacons, 3 m/s, 3 m/s^2 braking) was added for it.")
    add("")
    add("Remaining: in a drift the beacons of one wall are collinear, so a cycle of three ranges, or of a few with one")
    add("long (reflected) range, can fit a mirror image of the position across that wall; with one or two degrees of")
    add("freedom the chi-square test cannot see it. Those fixes (the fix-stage max column, 1-2.5 m) are refused by")
    add("the filter's gate (the rejected column); they raise the fix-stage RMSE and NEES, not the route errors. One")
    add("such fix taken as the initial position (the last fix before the alignment ends, while no belief exists)")
    add("would start the filter metres off; none did here, and recovering from it is issue 10's.")
    add("")
    add("The 2-D system assumes the receiver height (`z`, `z_sd`). A first draft of two scenarios let the floor dip")
    add("0.35 m under a flat roof, so the receiver rose to the beacons' height at the far end: the position block's")
    add("NEES was 10 per 3 dof (filter NEES 30). A site whose floor moves that much needs a 3-D fix or a height map.")
    return "\n".join(L)



def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--scenario", action="append", help="only these scenarios (default: all ABPS ones)")
    ap.add_argument("--no-noise-off", action="store_true")
    ap.add_argument("--json", help="write the rows here")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=YAML",
                    help="change the site config, e.g. sensors.abps.model.bridge=imu (a dotted path; the value is YAML)")
    args = ap.parse_args(argv)
    changes = {}
    for item in args.set:
        key, sep, value = item.partition("=")
        if not sep:
            ap.error(f"--set {item!r}: expected KEY=VALUE")
        changes[key] = yaml.safe_load(value)
    rows = study(args.seeds, tuple(args.scenario or SCENARIOS), not args.no_noise_off, changes=changes or None)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
