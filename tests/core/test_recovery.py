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


# ---------------------------------------------------------------- the trigger
from fusion.recovery import LockoutWatch, RecoverySpec


def _fix_system(lines, noise, initial_p, sd_p, recovery):
    spec = SystemSpec.model_validate({
        "name": "lock", "process": {"type": "pv", "dims": 2, "spectral_density": 1e-9},
        "initial": {"mean": {"p": list(initial_p), "v": [0.5, 0.3]}, "sd": {"p": sd_p, "v": 1e-4}},
        "filter": "ekf", "sensors": {"fix": {"model": {"type": "position"}, "noise": noise,
                                             "gate": {"type": "chi2", "probability": 0.999},
                                             "recovery": recovery}}})
    return wire(spec), lines


def _fix_lines(noise, n=200, dt=0.1, seed=1, bad=None):
    """A walk from (1, 1) at (0.5, 0.3) m/s, truth and fixes with ``noise`` m; ``bad(k, rng)`` adds an error."""
    rng = np.random.default_rng(seed)
    lines = ["# fields truth px py vx vy\n"]
    for k in range(n):
        t = k * dt
        p = np.array([1.0, 1.0]) + np.array([0.5, 0.3]) * t
        lines.append(f"{t!r},truth,{float(p[0])!r},{float(p[1])!r},0.5,0.3\n")
        z = p + rng.normal(0, noise, 2) + (bad(k, rng) if bad is not None else 0.0)
        lines.append(f"{t!r},fix,{float(z[0])!r},{float(z[1])!r}\n")
    return lines


def test_a_lockout_with_every_nis_just_over_the_gate_is_recovered():
    """Every fix refused with a NIS between the gate (13.8 on 2 dof) and twice it, so "each NIS at least
    nis_factor x threshold" would never fire; the fixes agree with each other: a lock-out, reset."""
    # belief 23 mm off with a 5 mm sd, fixes 1 mm: NIS ~ 0.023^2 / 2.6e-5 ~ 20, between 13.8 and 27.6
    lines = _fix_lines(0.001)
    rec = {"after_s": 1.0, "min_rejected": 3, "action": "reset", "blocks": ["p"]}
    system, _ = _fix_system(lines, 0.001, (1.023, 1.0), 0.005, {**rec, "nis_factor": 2.0})
    old = pipeline.run(system, lines).summary   # nis_factor 2: no reset, every fix refused
    assert old["health"]["resets"] == 0 and old["sensors"]["fix"]["used"] == 0
    assert old["health"]["locked_out"]["fix"]["rejected"] == 200   # and the summary says so
    system, _ = _fix_system(lines, 0.001, (1.023, 1.0), 0.005, rec)
    s = pipeline.run(system, lines).summary
    assert s["health"]["resets"] == 1 and s["sensors"]["fix"]["used"] >= 189
    # 10 refused over 0.9 s; the 11th, at 1 s, recovers (it is fused: an accepted update)
    assert s["health"]["rejected_in_a_row"]["fix"] == 10 and s["health"]["locked_out"] == {}
    assert s["errors"]["position_rmse_m"] < 0.023 * math.sqrt(11 / 200) + 0.002


def test_an_echo_burst_does_not_reset_a_good_filter():
    """Fixes 1 m off in random directions for 2 s (their own NIS far over the gate): they disagree with
    each other, so the belief, right all along, is kept; without the agreement test it is reset to one."""
    def burst(k, rng):
        if 50 <= k < 70:
            a = rng.uniform(0, 2 * np.pi)
            return np.array([np.cos(a), np.sin(a)])
        return 0.0
    lines = _fix_lines(0.05, bad=burst)
    rec = {"after_s": 1.0, "min_rejected": 3, "action": "reset", "blocks": ["p"]}
    system, _ = _fix_system(lines, 0.05, (1.0, 1.0), 0.05, rec)
    s = pipeline.run(system, lines).summary
    assert s["health"]["resets"] == 0 and 20 <= s["sensors"]["fix"]["rejected"] <= 22
    assert s["health"]["locked_out"]["fix"]["rejected"] == 20   # said, though no reset
    assert s["errors"]["position_max_m"] < 0.1
    system, _ = _fix_system(lines, 0.05, (1.0, 1.0), 0.05, {**rec, "agreement_probability": None})
    s = pipeline.run(system, lines).summary
    assert s["health"]["resets"] >= 1 and s["errors"]["position_max_m"] > 0.5


def test_the_watch_needs_agreeing_rejections_of_any_nis():
    spec = RecoverySpec(after_s=1.0, min_rejected=3)
    assert spec.nis_factor == 1.0 and spec.agreement_probability == 0.999
    S = np.eye(2) * 0.01
    w = LockoutWatch(spec)
    # a belief 1 m off drifting 0.2 m/s: innovations with a common offset and drift, NIS just over 13.8
    fired = [w.update(0.5 * k, False, 15.0, 13.8, np.array([1.0 + 0.1 * k, 0.5]) + 0.01 * (-1) ** k, S)
             for k in range(4)]
    assert fired == [False, False, True, True]
    w.clear()
    rng = np.random.default_rng(0)
    scattered = [w.update(0.5 * k, False, 100.0, 13.8, rng.normal(0, 1.0, 2), S) for k in range(20)]
    assert not any(scattered) and w.count < 3
    # a model of its own each (ranges to different beacons): compared within the model only
    w.clear()
    a, b = object(), object()
    out = [w.update(0.3 * k, False, 20.0, 10.8, np.array([0.5 if k % 2 else -0.5]), np.eye(1) * 0.01,
                    a if k % 2 else b) for k in range(8)]
    assert out[-1] and not out[2]
    # an accepted update ends the streak; with nis_factor 2, a NIS under twice the threshold does too
    w = LockoutWatch(RecoverySpec(after_s=1.0, min_rejected=3, nis_factor=2.0))
    assert not any(w.update(0.5 * k, False, 20.0, 13.8, np.array([1.0, 0.5]), S) for k in range(6))
