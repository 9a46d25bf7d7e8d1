"""Regenerate docs/results/real_flights.md: the real-vehicle configs on flight logs of every layout the
importers read, scored against the vehicle's own estimator in flight.

    python experiments/real_flights.py        # ~10 s: simulates, writes the logs, imports, runs, the page

Each log goes through the two commands a user runs (`fusion import LOG -o X.log`, `fusion run
configs/<vehicle>_ins_gps_mag.yaml --input X.log`), unchanged:
- the shared real PX4 log ../shared/logs/px4_sample_log_small.ulg (read in place, never copied; skipped
  when absent), a short ground run whose EKF2 never flags a horizontal position valid;
- synthetic logs of each layout from one simulated flight (experiments/flight_layouts.py), whose "onboard
  estimator" is the simulator's truth: older and newer ArduPilot DataFlash (GPS boot clock in ``T`` or
  ``TimeUS``), older and newer PX4 ULog topics, and one PX4 log written at 10 Hz (4 ms of each 100 ms).

Scored in flight (between the header's ``ARMED`` and ``DISARMED`` lines, fusion.importers.flight_events)
at the reference's times (the estimate interpolated, the quaternion by slerp): roll, pitch and yaw (ZYX
Euler angles, each difference wrapped to +-180 deg) RMSE and maximum, velocity RMSE (3-D), horizontal
position RMSE, and the run's real-time factor (log seconds per wall second).
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import contextlib  # noqa: E402
import csv  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "experiments"))
PX4_LOG = Path(os.environ.get("FUSION_TEST_LOGS", ROOT.parent / "shared" / "logs")) / "px4_sample_log_small.ulg"
PAGE = ROOT / "docs" / "results" / "real_flights.md"

from fusion.cli import main  # noqa: E402
from fusion.importers.flight_events import in_flight  # noqa: E402
from fusion.logformat import ParsedStream, iter_messages  # noqa: E402
import provenance  # noqa: E402  (experiments/, on the path: the page's provenance block)

#: The files the page is made from (their hashes go in its provenance block, experiments/provenance.py); the
#: shared PX4 log is outside the repository and read in place.
INPUTS = ("configs/px4_ins_gps_mag.yaml", "configs/ardupilot_ins_gps_mag.yaml", "experiments/flight_layouts.py",
          "tests/systems/ardupilot_synth.py")

CONFIG = {"bin": ROOT / "configs" / "ardupilot_ins_gps_mag.yaml", "ulg": ROOT / "configs" / "px4_ins_gps_mag.yaml"}
LABELS = {"dataflash_new": "ArduPilot 4.x DataFlash (synthetic)", "dataflash_old": "ArduPilot 3.3 DataFlash, older GPS (synthetic)",
          "ulog_new": "PX4 ULog, newer topics (synthetic)", "ulog_old": "PX4 ULog, older sensor_combined (synthetic)",
          "ulog_low_rate": "PX4 ULog logged at 10 Hz (synthetic)"}


def _read(rec: Path) -> tuple[dict, list[tuple[float, str]], np.ndarray, dict]:
    """(header meta, messages (t, text), reference times, reference columns by name) of a recording."""
    st = ParsedStream()
    lines = rec.read_text().splitlines()
    ref = [m for m in iter_messages(lines, st) if getattr(m, "sensor", "") == "reference"]
    msgs = []
    for line in lines:
        if line.startswith("# message ") and ":" in line:
            head, text = line[len("# message "):].split(":", 1)
            try:
                msgs.append((float(head), text.strip()))
            except ValueError:
                pass
    names = st.header.fields["reference"]
    rv = np.array([m.values for m in ref], float)
    return st.header.meta, msgs, np.array([m.t for m in ref]), {n: rv[:, i] for i, n in enumerate(names)}


def _euler(q: np.ndarray) -> np.ndarray:
    """(k, 3) roll, pitch, yaw (deg, ZYX) of body-to-NED quaternions ``[w x y z]``."""
    from scipy.spatial.transform import Rotation
    return Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_euler("ZYX", degrees=True)[:, ::-1]


def _slerp(t_q: np.ndarray, q: np.ndarray, t: np.ndarray) -> np.ndarray:
    from fusion.importers.common import slerp_to
    return slerp_to(t_q, q, t)


def score(rec: Path, est_csv: Path) -> dict:
    """In-flight agreement of the run's estimates with the recording's reference (see the module)."""
    _, msgs, t_ref, ref = _read(rec)
    rows = list(csv.DictReader(est_csv.open()))
    e = {k: np.array([float(r[k]) for r in rows]) for k in ("t", "px", "py", "vx", "vy", "vz", "qw", "qx", "qy", "qz")}
    spans = in_flight(msgs) or [(-np.inf, np.inf)]
    inside = np.zeros(len(t_ref), bool)
    for a, b in spans:
        inside |= (t_ref >= a) & (t_ref <= b)
    inside &= (t_ref >= e["t"][0]) & (t_ref <= e["t"][-1])
    t = t_ref[inside]
    out: dict = {"samples": int(inside.sum()), "in_flight_s": float(sum(min(b, t_ref[-1]) - max(a, t_ref[0])
                                                                       for a, b in spans))}
    if not inside.any():
        return out
    q_est = _slerp(e["t"], np.column_stack([e[c] for c in ("qw", "qx", "qy", "qz")]), t)
    q_ref = np.column_stack([ref[c][inside] for c in ("qw", "qx", "qy", "qz")])
    d = _euler(q_est) - _euler(q_ref)
    d = (d + 180.0) % 360.0 - 180.0
    for k, name in enumerate(("roll", "pitch", "yaw")):
        out[f"{name}_rmse"] = float(np.sqrt(np.mean(d[:, k] ** 2)))
        out[f"{name}_max"] = float(np.max(np.abs(d[:, k])))
    if all(c in ref for c in ("vx", "vy", "vz")):
        dv = np.column_stack([np.interp(t, e["t"], e[c]) - ref[c][inside] for c in ("vx", "vy", "vz")])
        out["vel_rmse"] = float(np.sqrt(np.mean(np.sum(dv ** 2, axis=1))))
    if all(c in ref for c in ("px", "py")):
        dp = np.column_stack([np.interp(t, e["t"], e[c]) - ref[c][inside] for c in ("px", "py")])
        out["hpos_rmse"] = float(np.sqrt(np.mean(np.sum(dp ** 2, axis=1))))
    return out


def run_one(log: Path, work: Path, name: str) -> dict:
    """Import ``log`` and run its vehicle's config on it (the two commands, in-process); the scores."""
    rec, est, summ = work / f"{name}.log", work / f"{name}.csv", work / f"{name}.json"
    config = CONFIG[log.suffix.lstrip(".")]
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["import", str(log), "-o", str(rec), "--force"]) == 0
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = main(["run", str(config), "--input", str(rec), "-o", str(est), "--summary-json", str(summ),
                     "--force"])
    summary = json.loads(summ.read_text())
    out = score(rec, est)
    out.update(config=config.name, exit=code, rtf=summary["duration_s"] / max(summary["wall_s"], 1e-9),
               coverage=summary.get("health", {}).get("imu_coverage", {}).get("imu", {}),
               warnings=[ln for ln in err.getvalue().splitlines() if ln.startswith("warning: imu: IMU coverage")])
    return out


def _f(v, digits: str = ".2f") -> str:
    return "-" if v is None else format(v, digits)


def page(results: list[tuple[str, dict]]) -> str:
    head = ("| log | config | in flight (s) | roll RMSE / max (deg) | pitch RMSE / max (deg) | yaw RMSE / max (deg) "
            "| velocity RMSE (m/s) | horizontal position RMSE (m) | real-time factor | exit |\n"
            "|---|---|---|---|---|---|---|---|---|---|\n")
    rows = []
    for label, r in results:
        ang = " | ".join(f"{_f(r.get(f'{a}_rmse'))} / {_f(r.get(f'{a}_max'))}" for a in ("roll", "pitch", "yaw"))
        rows.append(f"| {label} | {r['config']} | {r['in_flight_s']:.1f} | {ang} | {_f(r.get('vel_rmse'))} | "
                    f"{_f(r.get('hpos_rmse'))} | {r['rtf']:.0f} | {r['exit']} |")
    cov = [f"- {label}: " + (r["warnings"][0].removeprefix("warning: imu: ") if r["warnings"] else
                             f"coverage {_f(r['coverage'].get('fraction'), '.3g') if r['coverage'].get('fraction') is not None else 'not in the log'}, up to "
                             f"{r['coverage'].get('rotation_per_sample_deg')} deg between samples: no warning")
           for label, r in results if r.get("coverage")]
    return f"""# Real flights: the vehicle configs on logs of every layout

Regenerate: `python experiments/real_flights.py` (about 10 s; its commit and inputs: the provenance block at
the end). Each log: `fusion import
LOG -o X.log`, then `fusion run configs/<vehicle>_ins_gps_mag.yaml --input X.log`, unchanged. Scored in
flight (between the header's `ARMED` and `DISARMED` lines) against the vehicle's own estimator (the log's
`reference` lines) at its times: roll, pitch, yaw differences of the ZYX Euler angles, velocity (3-D) and
horizontal position; real-time factor = log seconds per wall second of the run.

The synthetic logs (experiments/flight_layouts.py) are one simulated 40 s flight written in each layout,
their "onboard estimator" the simulator's truth: their agreement is the error. `exit` is `fusion run`'s: 4
is a degraded run (its health says the estimate cannot be trusted, the line names why). The PX4 log is the shared
real one (a 6.5 s ground run of a Cube Orange; its EKF2 never flags a horizontal position or velocity
valid, hence the dashes; its yaw is EKF2's own heading still converging). The GPS of the synthetic logs
lags as the configs assume (0.2 s ArduPilot, 0.11 s PX4: `sensors.gps.time_offset`). The ArduPilot 3.3 log
has no `ORGN` record: its reference is referred to the recording's origin by its own position at the first
fix's stamp, which the GPS lag puts 0.2 s after the instant the fix measures, an offset its horizontal
position carries. Its GPS records carry no accuracies (no `GPA` before ArduPilot 3.4): the config's floor,
0.5 m (EK3_POSNE_M_NSE), is then below this simulated receiver's 0.7 m / 1.2 m, and the health rule finds
the GPS innovations inconsistent (exit 4), as it should.

{head}{chr(10).join(rows)}

## IMU coverage (`fusion run`'s check of the importer's header, fusion/imu_coverage.py)

{chr(10).join(cov)}

The 10 Hz log keeps 4 ms of gyro integral of every 100 ms: the motion between its samples is not in the
log, and `fusion run` says so once (the summary's `health.imu_coverage`); its figures above are what a
dead reckoning from such samples gives.
"""


def main_() -> int:
    import flight_layouts as fl

    results = []
    with tempfile.TemporaryDirectory() as d:
        work = Path(d)
        if PX4_LOG.is_file():
            results.append(("PX4 sample log (real, ground run)", run_one(PX4_LOG, work, "px4_real")))
        else:
            print(f"skipped: {PX4_LOG} is absent", file=sys.stderr)
        f = fl.flight()
        for layout in fl.LAYOUTS:
            path = work / (layout + (".bin" if layout.startswith("dataflash") else ".ulg"))
            fl.write(layout, f, path)
            results.append((LABELS[layout], run_one(path, work, layout)))
    provenance.write_page(PAGE, page(results), INPUTS)
    print(f"wrote {PAGE}")
    return 0


if __name__ == "__main__":
    sys.exit(main_())
