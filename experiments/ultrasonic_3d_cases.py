"""Paper 003 (3-D ultrasonic localiser): simulated recordings and the estimators run over them, for
experiments/ultrasonic_3d.py (Tables I-III) and the tests.

Every recording comes from the project's own simulator (``fusion.simulate`` on the scenarios
``ultrasonic_3d_static`` / ``ultrasonic_3d_walk`` with a seed and overrides) and is read back as a log: the
estimators only see what a log carries (arrivals and receivers), the scoring reads the truth lines.
"""
from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.spatial.transform import Rotation, Slerp

ROOT = Path(__file__).resolve().parents[1]
IEKF = ROOT / "configs" / "ultrasonic_3d_iekf.yaml"
POSE = ROOT / "configs" / "ultrasonic_3d_pose.yaml"


# --------------------------------------------------------------------------- recordings
def scenario(name: str, seed: int, **changes: Any):
    """The validated Scenario ``scenarios/<name>.yaml`` with ``seed`` and top-level / ``trajectory.`` /
    ``sensors.us.`` overrides (keys ``trajectory__start``, ``us__echo_prob``, ...)."""
    from fusion.simulate.scenario import Scenario

    data = yaml.safe_load((ROOT / "scenarios" / f"{name}.yaml").read_text())
    data["seed"] = seed
    if "seed" in data["trajectory"]:
        data["trajectory"]["seed"] = seed
    for key, value in changes.items():
        if key.startswith("trajectory__"):
            data["trajectory"][key[12:]] = value
        elif key.startswith("us__"):
            data["sensors"]["us"][key[4:]] = value
        elif key.startswith("truth__"):
            data["truth"][key[7:]] = value
        else:
            data[key] = value
    return Scenario.model_validate(data)


def write_log(sc, seed: int, tmpdir: str | None = None) -> str:
    """Simulate ``sc`` with ``seed`` into a temporary log file; returns its path (the caller removes it)."""
    from fusion.simulate import simulate

    fd, path = tempfile.mkstemp(prefix=f"us3d_{sc.name}_{seed}_", suffix=".log", dir=tmpdir)
    with os.fdopen(fd, "w") as fh:
        fh.write(simulate(sc, seed=seed))
    return path


@dataclass
class Log:
    """What a recording carries: arrivals (t, beacon, arrival, receiver) and the truth lines."""

    t: np.ndarray          # (k,) arrival message times (s)
    beacon: list[str]      # (k,)
    arrival: np.ndarray    # (k,) s
    receiver: np.ndarray   # (k,) 1-32
    truth_t: np.ndarray    # (m,)
    truth: dict[str, np.ndarray]

    def truth_at(self, t: np.ndarray) -> tuple[np.ndarray, Rotation]:
        """True position (k, 3) (linear interpolation) and attitude (Slerp) at times t."""
        p = np.column_stack([np.interp(t, self.truth_t, self.truth[k]) for k in ("px", "py", "pz")])
        q = np.column_stack([self.truth[k] for k in ("qw", "qx", "qy", "qz")])
        rot = Slerp(self.truth_t, Rotation.from_quat(q, scalar_first=True))(np.clip(t, self.truth_t[0],
                                                                                    self.truth_t[-1]))
        return p, rot


def read_log(path: str) -> Log:
    """The arrivals and truth of a log written by the arrival_time simulator."""
    t, beacon, arrival, receiver, tt, rows, names = [], [], [], [], [], [], None
    for line in Path(path).read_text().splitlines():
        if line.startswith("# fields truth "):
            names = line.split()[3:]
        if not line or line[0] == "#":
            continue
        parts = line.split(",")
        if parts[1] == "us":
            t.append(float(parts[0]))
            beacon.append(parts[2])
            arrival.append(float(parts[3]))
            receiver.append(int(float(parts[4])))
        elif parts[1] == "truth":
            tt.append(float(parts[0]))
            rows.append([float(v) for v in parts[2:]])
    R = np.array(rows)
    return Log(np.array(t), beacon, np.array(arrival), np.array(receiver), np.array(tt),
               {n: R[:, i] for i, n in enumerate(names)})


def echoes(log: Log, beacons: dict[str, np.ndarray], c: float = 340.0, min_extra_m: float = 0.15) -> np.ndarray:
    """Boolean (k,): arrivals later than the direct path by more than ``min_extra_m`` (the simulator's
    echoes have 0.3-3 m of extra path; 0.15 m is 2.2 sd of the 0.2 ms noise), from the truth lines: the
    firing times are the distinct values of truth ``t_fire`` (truth is sampled faster than the firings),
    the pulse's firing the latest one before its arrival."""
    fires = np.unique(log.truth["t_fire"])
    fire = fires[np.searchsorted(fires, log.arrival, side="right") - 1]
    p, _ = log.truth_at(log.t)
    d = np.linalg.norm(p - np.array([beacons[b] for b in log.beacon]), axis=1)
    return (log.arrival - fire - d / c) * c > min_extra_m


# --------------------------------------------------------------------------- running systems
def run_system(system, path: str, smooth: bool = False) -> dict[str, Any]:
    """Replay ``system`` over the log at ``path``: {"summary", "t", "x", "sd", "accepted", "P_last"}
    (estimates at each update; ``accepted`` (k,) whether the update's measurement passed the gate,
    ``P_last`` the last covariance). ``smooth``: the Rauch-Tung-Striebel smoothed run
    (``fusion.smoothing.run_smoothed``, as ``fusion run --smooth``): the estimates are the smoothed ones
    and the summary carries both the filtered errors and ``smoothed``. (The one place that calls the run
    loop.)"""
    from fusion import pipeline
    from fusion.smoothing import run_smoothed

    kept = pipeline.Collect()
    summary = (run_smoothed if smooth else pipeline.run)(system, path, [kept]).summary
    est = [e for e in kept.estimates if e.reason == "update"]
    return {"summary": summary, "t": np.array([e.t for e in est]), "x": np.array([e.belief.x for e in est]),
            "sd": np.array([e.belief.sd for e in est]), "system": system,
            "accepted": np.array([bool(e.update.accepted) if e.update is not None else True for e in est]),
            "P_last": est[-1].belief.cov if est else None}


def load(config: Path, preprocessor: dict | None = None, **process_changes):
    """A wired system of ``config`` with its process parameters (and those of sensor ``us``'s
    preprocessor) changed."""
    from fusion.config import SystemSpec, wire
    from fusion.yamlsource import load_yaml

    doc = load_yaml(config)
    data = dict(doc.data)
    data["process"] = {**data["process"], **process_changes}
    if preprocessor:
        us = dict(data["sensors"]["us"])
        us["preprocessor"] = {**us["preprocessor"], **preprocessor}
        data["sensors"] = {**data["sensors"], "us": us}
    return wire(SystemSpec.model_validate(data), None, Path(config))


def axis_error_deg(C_true: np.ndarray, C_est: np.ndarray) -> np.ndarray:
    """Paper 003 sec. 6.2: the largest angle (deg) between corresponding axes (columns) of two frames
    (..., 3, 3)."""
    cos = np.clip(np.einsum("...ij,...ij->...j", C_true, C_est), -1.0, 1.0)
    return np.rad2deg(np.arccos(cos)).max(axis=-1)


# --------------------------------------------------------------------------- orientation estimators
def geometric_orientation(log: Log, beacons: dict[str, np.ndarray], true_position: bool, period: float = 0.225,
                          c: float = 340.0) -> tuple[np.ndarray, np.ndarray]:
    """Sec. 5.1 at every firing from the last four (one per beacon): C_b^n (k, 3, 3) and valid (k,). The
    position is the truth (the paper's Monte Carlo: discretisation only) or the TDOA fix of the same four."""
    from fusion_plugins.measurement.direction import receiver_normals as _normals
    from fusion_plugins.solvers.orientation_geometric import orientation_fix
    from fusion_plugins.solvers.tdoa_geometric import NoFix, tdoa_fix

    N = _normals("truncated_icosahedron")
    k = len(log.t)
    out = np.tile(np.eye(3), (k, 1, 1))
    ok = np.zeros(k, bool)
    p_true, _ = log.truth_at(log.t) if true_position else (None, None)
    prev = None
    for j in range(3, k):
        idx = np.arange(j - 3, j + 1)
        names = [log.beacon[i] for i in idx]
        if len(set(names)) < 4:
            continue
        B = np.array([beacons[n] for n in names])
        try:
            if true_position:
                r = p_true[j]
            else:
                a = log.arrival[idx]
                r, _, _ = tdoa_fix(B, a, np.rint((a - a[0]) / period), period, c,
                                   prev if prev is not None else B.mean(axis=0))
                prev = r
            dirs = (B - r) / np.linalg.norm(B - r, axis=1, keepdims=True)
            out[j] = orientation_fix(N[log.receiver[idx] - 1], dirs)
            ok[j] = True
        except NoFix:
            prev = None
    return out, ok


def orientation_filter(log: Log, beacons: dict[str, np.ndarray], positions: np.ndarray, C0: np.ndarray,
                       angle_sd_deg: float = 0.57, sd_deg: float | None = None) -> tuple[np.ndarray, float]:
    """The paper's orientation IEKF (sec. 5.2): static_orientation (identity transition, random walk) and the
    direction of each firing (eq. 19) at the position ``positions`` (k, 3) of the position filter, from the
    attitude C0 (3, 3). Returns C_b^n (k, 3, 3) after each firing and the mean update time (s)."""
    from fusion import quaternion as quat
    from fusion import testing
    from fusion.api import Belief, BuildContext, Message
    from fusion_plugins.process.static_orientation import attitude_noise

    proc = testing.build("process", "static_orientation", {"angle_sd_deg": angle_sd_deg})
    ctx = BuildContext(layout=proc.layout, beacons=beacons)
    params: dict[str, Any] = {"position": [0.0, 0.0, 0.0]}
    if sd_deg is not None:
        params["sd_deg"] = sd_deg
    model = testing.build("measurement", "direction", params, ctx)
    flt = testing.build("filter", "iekf", {"max_iterations": 10, "tolerance": 1e-9})
    q0 = quat.from_matrix(C0)
    belief = Belief(log.t[0], q0, P=attitude_noise(q0, np.deg2rad(15.0) ** 2, 1e-6))
    out = np.empty((len(log.t), 3, 3))
    t_up = 0.0
    for j, t in enumerate(log.t):
        belief = flt.predict(belief, proc, None, t - belief.t) if t > belief.t else belief
        obs = model.observe(Message(t, "us", (log.beacon[j], log.arrival[j], float(log.receiver[j]))))
        m = obs.model.at(positions[j])
        t0 = time.perf_counter()
        belief = flt.update(belief, m, obs.z, obs.R).belief
        t_up += time.perf_counter() - t0
        out[j] = quat.to_matrix(belief.x)
    return out, t_up / len(log.t)
