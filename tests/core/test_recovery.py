"""Recovery from lock-out (issue 10 item 7, fusion.recovery) and the summary's health (item 6)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from fusion import pipeline
from fusion.api import ConfigError
from fusion.config import SystemSpec, wire


def _walk(n=400, dt=0.1, seed=3):
    """Truth of a 2-D walk starting at (1, 1) and the lines of position fixes (sd 0.1 m) and ranges."""
    rng = np.random.default_rng(seed)
    lines = ["# fields truth px py vx vy\n"]
    beacons = {"B1": (0.0, 0.0), "B2": (20.0, 0.0), "B3": (20.0, 20.0), "B4": (0.0, 20.0)}
    p, v = np.array([1.0, 1.0]), np.array([0.5, 0.3])
    for k in range(n):
        t = k * dt
        p = p + v * dt
        px, py = (float(a) for a in p)
        lines.append(f"{t!r},truth,{px!r},{py!r},{float(v[0])!r},{float(v[1])!r}\n")
        fx, fy = (float(a) for a in p + rng.normal(0, 0.1, 2))
        lines.append(f"{t!r},fix,{fx!r},{fy!r}\n")
        name = f"B{k % 4 + 1}"
        lines.append(f"{t!r},uwb,{name},{math.dist(p, beacons[name]) + float(rng.normal(0, 0.1))!r}\n")
    return lines, beacons


def _system(sensor: str, recovery=None):
    lines, beacons = _walk()
    sensors = {"fix": {"model": {"type": "position"}, "noise": 0.1},
               "uwb": {"model": "range", "noise": 0.1}}
    s = {**sensors[sensor], "gate": {"type": "chi2", "probability": 0.999}}
    if recovery is not None:
        s["recovery"] = recovery
    spec = SystemSpec.model_validate({
        "name": "lock", "beacons": {k: list(v) for k, v in beacons.items()},
        "process": {"type": "pv", "dims": 2, "spectral_density": 1e-6},
        # confidently wrong: 8 m off with a 5 cm sd, so every measurement fails the gate
        "initial": {"mean": {"p": [9.0, 7.0], "v": [0.5, 0.3]}, "sd": {"p": 0.05, "v": 0.001}},
        "filter": "ekf", "sensors": {sensor: s}})
    return wire(spec), [ln for ln in lines if f",{sensor}," in ln or ",truth," in ln or ln.startswith("#")]


def test_without_recovery_the_filter_stays_locked_out():
    system, lines = _system("fix")
    s = pipeline.run(system, lines).summary
    assert s["sensors"]["fix"]["used"] < 5 and s["health"]["resets"] == 0
    assert s["errors"]["position_rmse_m"] > 5.0
    assert s["health"]["longest_without_accepted_s"]["fix"] > 30.0


def test_reset_reinitialises_the_position_from_the_fix():
    system, lines = _system("fix", {"after_s": 1.0, "min_rejected": 3, "action": "reset", "blocks": ["p"]})
    kept = pipeline.Collect()
    s = pipeline.run(system, lines, [kept]).summary
    assert s["health"]["resets"] == 1 and s["events"]["reset"] == 1
    assert s["sensors"]["fix"]["used"] > 380
    assert s["health"]["longest_without_accepted_s"]["fix"] == pytest.approx(1.0, abs=0.11)
    # ~11 estimates 8-10 m off before the reset, then within the fixes' noise: RMSE^2 ~ 11 * 10^2 / 400
    assert s["errors"]["position_rmse_m"] < math.sqrt(12 * 10.0 ** 2 / 400)
    last = kept.estimates[-1]
    truth_end = np.array([1.0, 1.0]) + np.array([0.5, 0.3]) * (last.t + 0.1)
    assert np.linalg.norm(last.belief.x[:2] - truth_end) < 0.2


def test_inflate_lets_ranges_pull_the_belief_back():
    # sd 0.05 m x 100 = 5 m: the 8 m error is then within ~2 sigma, and the ranges pull the belief back
    system, lines = _system("uwb", {"after_s": 1.0, "action": "inflate", "inflate": 100.0, "blocks": ["p", "v"]})
    kept = pipeline.Collect()
    s = pipeline.run(system, lines, [kept]).summary
    assert s["health"]["resets"] == 1 and s["sensors"]["uwb"]["used"] > 380
    last = kept.estimates[-1]
    truth_end = np.array([1.0, 1.0]) + np.array([0.5, 0.3]) * (last.t + 0.1)
    assert np.linalg.norm(last.belief.x[:2] - truth_end) < 0.3 and s["health"]["final_estimate_finite"]


def test_recovery_config_is_checked():
    system, _ = _system("fix", {"blocks": ["p"]})
    assert system.sensors["fix"].recovery.after_s == 2.0
    with pytest.raises(ConfigError, match="state has no block 'q'"):
        _system("fix", {"blocks": ["q"]})
    with pytest.raises(ConfigError, match="measures 1 value.*use action: inflate"):
        _system("uwb", {"action": "reset", "blocks": ["p"]})


def test_health_reports_a_non_finite_end():
    """Health: divergence counted, last estimate flagged (the CLI then exits 3)."""
    from fusion.api import Belief, Estimate
    from fusion.config import load_system
    from pathlib import Path

    system = load_system(Path(__file__).resolve().parents[2] / "configs" / "example_2d.yaml")
    run = pipeline.Run(system)
    for t, x in ((0.0, [1.0, 1.0, 0.0, 0.0]), (1.0, [np.nan, 1.0, 0.0, 0.0]), (3.0, [np.nan, 1.0, 0.0, 0.0])):
        run._dispatch(Estimate(t, Belief(t, np.array(x), P=np.eye(4)), "output"))
    h = run.finish().summary["health"]
    assert h["nonfinite_estimates"] == 2 and h["final_estimate_finite"] is False and h["diverged_s"] == 2.0
