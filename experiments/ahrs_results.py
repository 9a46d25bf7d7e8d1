"""docs/results/ahrs.md: configs/ahrs.yaml (IMU + magnetometer AHRS, issue 32 item 3) on simulated handheld
motion over seeds: roll, pitch and yaw RMSE, NEES, with and without the magnetic disturbance, variants,
real-time factor.

    python experiments/ahrs_results.py              # 4 seeds, ~2 min; writes docs/results/ahrs.md
    python experiments/ahrs_results.py --seeds 8

Each seed simulates scenarios/ahrs_handheld.yaml (MPU-9250 data-sheet noises; a 15 uT disturbance at
40-50 s) and the same scenario without the disturbance, and runs the config (and its variants) on both.
Errors: Euler angle differences (estimate minus truth, wrapped) over the estimates after the static start;
the attitude NEES is on 3 dof (the navigation-frame error against the q block's covariance, as
``attitude.covariance_in_state`` maps it), the summary's NEES on 6 (attitude and gyro bias).
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import copy  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "ahrs.yaml"
SCENARIO = ROOT / "scenarios" / "ahrs_handheld.yaml"
OUT = ROOT / "docs" / "results" / "ahrs.md"
INPUTS = ("configs/ahrs.yaml", "scenarios/ahrs_handheld.yaml")
DISTURBED = (40.0, 50.0)
START = 10.0                      # s: the static start ends

from fusion import quaternion as quat  # noqa: E402
from fusion.config import SystemSpec, wire  # noqa: E402
from fusion.simulate import simulate_file  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import provenance  # noqa: E402  (experiments/, on the path: the page's provenance block)

PLAIN_MAG = {"type": "magnetometer"}
AHRS_PACKAGE = "ahrs.filters.EKF (ahrs package)"
VARIANTS = {
    "shipped": ({}, "configs/ahrs.yaml as shipped"),
    "angular_accel_sd 3": ({"process.angular_accel_sd": 3.0}, "the hold-error noise at the hand's rms angular "
                           "acceleration"),
    "angular_accel_sd 0": ({"process.angular_accel_sd": 0.0}, "no hold-error noise (data-sheet gyro noise only)"),
    "gate only": ({"sensors.mag.model": PLAIN_MAG}, "magnetometer with the chi2 gate, no intensity or dip check"),
    "no disturbance handling": ({"sensors.mag.model": PLAIN_MAG, "sensors.mag.gate": None},
                                "magnetometer fused as it comes"),
    "fixed accelerometer R": ({"sensors.acc.model.adaptive": False, "sensors.acc.model.max_deviation": None},
                              "gravity without the |f| term and gate (R from motion_sd alone)"),
}


def config_data(changes: dict, log: Path) -> dict:
    data = yaml.safe_load(CONFIG.read_text())
    data["recording"] = str(log)
    for path, value in changes.items():
        node = data
        *head, last = path.split(".")
        for key in head:
            node = node[key]
        if value is None:
            node.pop(last, None)
        else:
            node[last] = copy.deepcopy(value)
    return data


def simulate(tmp: Path, seed: int, disturbed: bool) -> Path:
    sc = yaml.safe_load(SCENARIO.read_text())
    if not disturbed:
        sc["sensors"]["mag"]["disturbances"] = []
    path = tmp / f"scenario_{int(disturbed)}.yaml"
    path.write_text(yaml.safe_dump(sc, sort_keys=False))   # sensor order: the imu first (its truth biases)
    log = tmp / f"ahrs_{seed}_{int(disturbed)}.log"
    log.write_text(simulate_file(str(path), seed=seed))
    return log


def truth_of(log: Path) -> tuple[np.ndarray, np.ndarray]:
    lines = log.read_text().splitlines()
    fields = next(ln.split()[3:] for ln in lines if ln.startswith("# fields truth"))
    T = np.array([[float(v) for v in ln.split(",")[:1] + ln.split(",")[2:]] for ln in lines if ",truth," in ln])
    cols = [1 + fields.index(n) for n in ("qw", "qx", "qy", "qz")]
    return T[:, 0], T[:, cols]


def run_one(changes: dict, log: Path) -> dict:
    from fusion.pipeline import Collect, run

    system = wire(SystemSpec.model_validate(config_data(changes, log)), None, CONFIG)
    sink = Collect()
    c0 = time.process_time()
    summary = run(system, log, [sink]).summary
    cpu = time.process_time() - c0
    est = [e for e in sink.estimates if e.t >= START]
    t = np.array([e.t for e in est])
    q = quat.normalize(np.array([e.belief.x[0:4] for e in est]))
    P = np.array([e.belief.cov[0:4, 0:4] for e in est])
    tt, qt = truth_of(log)
    qt = quat.normalize(np.column_stack([np.interp(t, tt, qt[:, i]) for i in range(4)]))
    d = quat.multiply(q, quat.conjugate(qt))
    d *= np.where(d[:, :1] < 0, -1.0, 1.0)
    dth = 2.0 * d[:, 1:]                                          # navigation frame, rad
    M = 2.0 * np.swapaxes(quat.right_matrix(q)[:, :, 1:], 1, 2)   # d theta = 4 G^T dq, G = R(q)[:, 1:] / 2
    Pth = M @ P @ np.swapaxes(M, 1, 2)
    nees = np.einsum("ki,ki->k", dth, np.linalg.solve(Pth, dth[:, :, None])[:, :, 0])
    return {**errors(t, q, qt), "nees_att": float(nees.mean()), "nees": summary["consistency"]["nees_mean"],
            "cpu": cpu, "duration": summary["duration_s"], "mag": summary["sensors"]["mag"]}


def errors(t: np.ndarray, q: np.ndarray, qt: np.ndarray) -> dict:
    """Euler angle RMSE (deg, wrapped), total angle RMSE and the largest error in the disturbed window."""
    de = np.degrees(quat.to_euler(q) - quat.to_euler(qt))
    de = (de + 180.0) % 360.0 - 180.0
    ang = np.degrees(quat.angle_between(q, qt))
    dist = (t >= DISTURBED[0]) & (t < DISTURBED[1] + 5.0)
    return {"rmse": np.sqrt((de ** 2).mean(axis=0)), "total": float(np.sqrt((ang ** 2).mean())),
            "max_dist": float(ang[dist].max())}


def ahrs_package(log: Path) -> dict | None:
    """ahrs.filters.EKF (the ``ahrs`` package, its default noises) on the same samples, or None without it:
    the IMU at 100 Hz, the latest magnetometer sample held at each, the dip from the header, the gyro rates
    minus the static start's mean (it has no bias state), started at the true attitude. Its accelerometer
    convention is the reaction to gravity (+g up at rest), the negative of the specific force here."""
    try:
        from ahrs.filters import EKF
    except ImportError:
        return None
    lines = log.read_text().splitlines()
    rows = lambda s: np.array([[float(v) for v in ln.split(",")[:1] + ln.split(",")[2:]] for ln in lines if s in ln])
    imu, mag = rows(",imu,"), rows(",mag,")
    field = next(np.array(ln.split(":")[1].split(), float) for ln in lines if "mag earth_field_ned" in ln)
    t = imu[:, 0]
    m = mag[np.clip(np.searchsorted(mag[:, 0], t, side="right") - 1, 0, len(mag) - 1), 1:]
    tt, qt = truth_of(log)
    qt = quat.normalize(np.column_stack([np.interp(t, tt, qt[:, i]) for i in range(4)]))
    bias = imu[t < START - 1.0, 4:7].mean(axis=0)
    dip = float(np.degrees(np.arcsin(field[2] / np.linalg.norm(field))))
    ekf = EKF(gyr=imu[:, 4:7] - bias, acc=-imu[:, 1:4], mag=m, frequency=100.0, frame="NED", magnetic_ref=dip,
              q0=qt[0])
    keep = t >= START
    return {**errors(t[keep], quat.normalize(ekf.Q[keep]), qt[keep]), "nees_att": float("nan"),
            "nees": float("nan")}


def table(rows: dict[str, list[dict]], disturbed: bool) -> list[str]:
    out = ["| variant | roll | pitch | yaw | total | max 40-55 s | NEES att. (3) | NEES (6) |",
           "|---|---|---|---|---|---|---|---|"]
    for name, runs in rows.items():
        r = np.mean([x["rmse"] for x in runs], axis=0)
        mx = f"{np.mean([x['max_dist'] for x in runs]):.2f}" if disturbed else "-"
        m = {k: np.mean([x[k] for x in runs]) for k in ("total", "nees_att", "nees")}
        out.append(f"| {name} | {r[0]:.2f} | {r[1]:.2f} | {r[2]:.2f} | {m['total']:.2f} | {mx} "
                   f"| {m['nees_att']:.2f} | {m['nees']:.2f} |")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=4)
    args = ap.parse_args(argv)
    seeds = list(range(1, args.seeds + 1))
    res: dict[bool, dict[str, list[dict]]] = {True: {}, False: {}}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            for disturbed in (False, True):
                log = simulate(Path(tmp), seed, disturbed)
                names = VARIANTS if disturbed else ["shipped", "angular_accel_sd 3", "angular_accel_sd 0"]
                for name in names:
                    res[disturbed].setdefault(name, []).append(run_one(VARIANTS[name][0], log))
                    print(f"seed {seed} disturbed={disturbed} {name}: {res[disturbed][name][-1]['total']:.2f} deg",
                          file=sys.stderr)
                other = ahrs_package(log)
                if other is not None:
                    res[disturbed].setdefault(AHRS_PACKAGE, []).append(other)
    shipped = res[True]["shipped"] + res[False]["shipped"]
    rtf = np.mean([r["duration"] / r["cpu"] for r in shipped])
    rej = np.mean([r["mag"]["rejected"] for r in res[True]["shipped"]])
    rej0 = np.mean([r["mag"]["rejected"] for r in res[False]["shipped"]])
    lines = ["# AHRS: IMU + magnetometer, no GPS (configs/ahrs.yaml)", "",
             "Regenerate: `python experiments/ahrs_results.py` (speed: `python benchmarks/bench_ahrs.py`).", "",
             f"Simulated handheld motion (scenarios/ahrs_handheld.yaml: MPU-9250 data-sheet noises, gyro 100 Hz, "
             f"accelerometer and magnetometer fused at 25 Hz, 10 s static then 60 s of hand motion up to ~90 deg/s), "
             f"seeds {seeds[0]}-{seeds[-1]}, means over seeds. Errors in degrees after the static start: Euler "
             "angle RMSE (roll, pitch, yaw), total = RMSE of the rotation angle between estimate and truth. NEES: "
             "attitude on 3 dof; the run summary's on 6 (attitude and gyro bias); a consistent filter gives its dof.",
             "", "## Undisturbed field", ""]
    lines += table(res[False], False)
    lines += ["", "## A 15 uT magnetic disturbance at 40-50 s", "",
              "The column `max 40-55 s` is the largest attitude error while the field is disturbed and 5 s after.", ""]
    lines += table(res[True], True)
    lines += ["", f"Magnetometer samples rejected (shipped config): {rej:.0f} of 1751 with the disturbance, {rej0:.0f} "
              "without (225 of them are the static start's, used by the alignment; the others by the intensity "
              "and dip checks and the chi2 gate).", "",
              "## Speed", "",
              f"The filter alone (fusion.pipeline.run, CPU time): {rtf:.0f}x real time at the native 100 Hz. The "
              "whole process (start-up included) and the cost of an attitude update against the ins predict: "
              "benchmarks/results/ahrs.md.", "",
              "## Variants", ""]
    lines += [f"- **{k}**: {v[1]}." for k, v in VARIANTS.items()]
    lines += [f"- **{AHRS_PACKAGE}**: the `ahrs` package's EKF (if installed: `pip install ahrs`) on the same "
              "samples with its default noises (0.3^2, 0.5^2, 0.8^2), the IMU at 100 Hz and the latest magnetometer "
              "sample held, the static start's mean rate removed from the gyros (it has no bias state), started "
              "at the true attitude; its covariance is not compared (NEES nan)."]
    lines += ["", "## Reading", "",
              "- The largest modelling error is not a sensor's: the run loop holds each gyro sample until the next "
              "one, and a hand's changing rate makes that a lag of ~w dt / 2 (0.1-0.3 deg at 100 Hz). With the "
              "data-sheet gyro noise alone (angular_accel_sd 0) the attitude NEES is ~10x its dof; "
              "the process's angular_accel_sd covers it (docs in plugins/process/gyro_attitude.py).",
              "- The simulated disturbance is a step (15 uT at once): the chi2 gate alone already rejects it, so "
              "`gate only` equals the shipped checks here. The intensity and dip checks are for what a gate "
              "lets in: a disturbance that grows slowly, or one met while the attitude is uncertain; the "
              "simulator has no ramped disturbance yet, so that case is not measured.",
              "- The dip check skips samples while |f| is more than 1 m/s^2 from g and otherwise rejects "
              "a dip 5 deg off; a hand's acceleration across gravity tilts f unseen by |f|, so some clean samples "
              "are rejected in motion (the undisturbed count above minus the static start's 225)."]
    lines += ["", "## Not measured here", "",
              "Real data: the issue's handheld recordings with optical truth are not in the repository; "
              "the figure on real motion is still to be documented."]
    provenance.write_page(OUT, "\n".join(lines) + "\n", list(INPUTS))
    print(f"wrote {OUT}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
