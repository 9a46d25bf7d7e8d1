"""The scheduler's optional capabilities (fusion.api): AlignsState (TRIAD alignment over the static start),
UsesInput (a TRIAD preprocessor reads the accelerometer at each magnetometer sample) and PseudoMeasurement
(quat_norm after every prediction, paper 002 eq. 9)."""
from __future__ import annotations

import numpy as np
import yaml

from fusion import quaternion as quat
from fusion.config import load_system
from fusion_plugins.solvers.triad import TriadSolver

G = 9.80665
M_N = [17.81, -6.66, -13.81]


def _run(system, log):
    """(estimates, the scheduler at the end, summary): the one place that runs a system (fusion.pipeline)."""
    from fusion.pipeline import Collect, run

    sink = Collect()
    res = run(system, log, [sink])
    return sink.estimates, res.stats.scheduler, res.summary


def write_log(path, q_of_t, T=3.0, imu_hz=50, mag_hz=6):
    lines = ["# fields imu ax ay az gx gy gz", "# fields mag mx my mz"]
    ev = [(k / imu_hz, 0, "imu") for k in range(int(T * imu_hz) + 1)] + \
         [(k / mag_hz, 1, "mag") for k in range(int(T * mag_hz) + 1)]
    for t, _, s in sorted(ev):
        C = quat.to_matrix(q_of_t(t))
        if s == "imu":
            f = C.T @ np.array([0.0, 0.0, -G])
            lines.append(f"{t:.6f},imu," + ",".join(f"{v:.12f}" for v in (*f, 0.0, 0.0, 0.0)))
        else:
            m = C.T @ np.array(M_N)
            lines.append(f"{t:.6f},mag," + ",".join(f"{v:.12f}" for v in m))
    path.write_text("\n".join(lines) + "\n")


def config(path, mag, extra_sensors=None, process=None, align_s=1.0, q0=(1, 0, 0, 0)):
    cfg = {
        "name": "cap",
        "process": {"type": "ins", "states": 10, "gravity": G, **(process or {})},
        "initial": {"mean": {"p": 0.0, "v": 0.0, "q": list(q0)}, "sd": {"p": 1.0, "v": 0.1, "q": 0.02},
                    "align_s": align_s},
        "filter": "ekf",
        "sensors": {"imu": {"role": "input"}, "mag": mag, **(extra_sensors or {})},
    }
    path.write_text(yaml.safe_dump(cfg))
    return load_system(path)


MAG_VECTOR = {"model": {"type": "magnetometer", "field_ned": M_N, "align": "improved_triad"},
              "noise": {"sd": 0.1}}


def test_triad_alignment_sets_yaw_from_the_static_start(tmp_path):
    q_true = quat.from_euler(0.05, -0.08, 2.2)              # yaw 126 deg: far from the configured identity
    write_log(tmp_path / "a.log", lambda t: q_true)
    system = config(tmp_path / "a.yaml", MAG_VECTOR)
    est, _, s = _run(system, tmp_path / "a.log")
    first = est[0].belief
    assert quat.angle_between(first.x[6:10], q_true) < 1e-6   # exact vectors: exact attitude
    sd_q = np.sqrt(np.diag(first.cov)[6:10])
    assert np.all(sd_q < 0.01)                                # covariance from the sensors, not the config's 0.02
    assert s["sensors"]["mag"]["rejected"] == 0                # gathered, not "before the filter is initialised"
    # without the capability's alignment the yaw stays wrong
    system = config(tmp_path / "b.yaml", {**MAG_VECTOR, "model": {**MAG_VECTOR["model"], "align": "none"}})
    est, _, s = _run(system, tmp_path / "a.log")
    assert quat.angle_between(est[0].belief.x[6:10], q_true) > 1.0


def test_triad_preprocessor_reads_the_latest_input_sample(tmp_path, monkeypatch):
    """The attitude switches at t = 1.5 s (imu and mag of 1.5 s agree with the new one): the fix of the
    magnetometer sample at 1.5 s must use the specific force of 1.5 s, not an older one."""
    qa, qb = quat.from_euler(0.0, 0.0, 0.3), quat.from_euler(0.3, -0.2, 0.3)
    write_log(tmp_path / "s.log", lambda t: qa if t < 1.5 - 1e-9 else qb)
    mag = {"preprocessor": {"type": "triad", "field_ned": M_N, "gravity": G, "accel_disturbance_sd": 0.0},
           "model": "attitude"}
    system = config(tmp_path / "s.yaml", mag, align_s=0.0)
    fixes = []
    feed = TriadSolver.feed

    def recording_feed(self, m):                    # on the class: a run may work on copies of the system
        out = feed(self, m)
        fixes.extend(out)
        return out
    monkeypatch.setattr(TriadSolver, "feed", recording_feed)
    _run(system, tmp_path / "s.log")
    at = {round(f.t, 3): f.attitude for f in fixes}
    assert quat.angle_between(at[1.5], qb) < 1e-9 and quat.angle_between(at[1.333], qa) < 1e-9


def test_quat_norm_runs_after_every_prediction_and_restores_the_norm(tmp_path):
    write_log(tmp_path / "q.log", lambda t: np.array([1.0, 0, 0, 0]), T=2.0)
    free = {"process": {"renormalize": False}, "q0": (1.05, 0, 0, 0), "align_s": 0.0}
    system = config(tmp_path / "n.yaml", {"enabled": False}, **free)
    _, sched, _ = _run(system, tmp_path / "q.log")
    assert abs(np.linalg.norm(sched.belief.x[6:10]) - 1.05) < 1e-9   # the closed form keeps |q|
    system = config(tmp_path / "p.yaml", {"enabled": False}, {"qn": {"model": {"type": "quat_norm", "sd": 1e-3}}}, **free)
    _, sched, s = _run(system, tmp_path / "q.log")
    q = sched.belief.x[6:10]
    assert abs(np.linalg.norm(q) - 1.0) < 1e-3
    assert s["sensors"]["qn"]["used"] == s["steps"]["predict"] > 90


def test_magnetometer_updates_false_only_aligns(tmp_path):
    q_true = quat.from_euler(0.0, 0.0, -1.0)
    write_log(tmp_path / "u.log", lambda t: q_true)
    mag = {**MAG_VECTOR, "model": {**MAG_VECTOR["model"], "updates": False}}
    system = config(tmp_path / "u.yaml", mag)
    _, sched, s = _run(system, tmp_path / "u.log")
    assert quat.angle_between(sched.belief.x[6:10], q_true) < 1e-6
    n_static = sum(1 for k in range(19) if k / 6 < 1.0 - 1e-9)    # the samples before the filter starts at 1 s
    assert s["sensors"]["mag"]["used"] == n_static and s["steps"]["update"] == 0
