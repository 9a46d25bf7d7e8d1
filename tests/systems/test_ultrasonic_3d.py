"""Paper 003, the 3-D ultrasonic localiser: both configs end to end on their shipped recordings (through the
CLI, as a user runs them), and the position IEKF on fresh simulated recordings (seeds of the project's own
simulator), where its error must match its own covariance."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from fusion.cli import main

ROOT = Path(__file__).resolve().parents[2]
IEKF = ROOT / "configs" / "ultrasonic_3d_iekf.yaml"
POSE = ROOT / "configs" / "ultrasonic_3d_pose.yaml"


def _cli(tmp_path, config, *args):
    out = tmp_path / "s.json"
    assert main(["run", str(config), "-q", "--summary-json", str(out), *args]) == 0
    return json.loads(out.read_text())


def test_iekf_config_on_its_recording(tmp_path):
    s = _cli(tmp_path, IEKF)
    us = s["sensors"]["us"]
    assert us["malformed"] == 0 and us["late"] == 0
    # 2 % echoes + 4.6 % of genuine arrivals outside a 2-sigma gate: about 6-7 % rejected
    assert 0.03 < us["rejected"] / us["received"] < 0.12
    # the per-firing filter beats a single geometric fix (sd ~ 80 mm per axis here) by far
    assert s["errors"]["position_rmse_m"] < 0.08
    assert 1.0 < s["consistency"]["nees_mean"] < 6.0


@pytest.mark.parametrize("seed,first_fire", [(21, 0.137), (22, 120.0)])
def test_iekf_on_fresh_walks(tmp_path, seed, first_fire):
    """The walk scenario with another seed (and 5 % echoes): same config, consistent error; also when the
    beacons start firing two minutes into the log (the initial firing time is anything)."""
    import yaml

    scen = yaml.safe_load((ROOT / "scenarios" / "ultrasonic_3d_walk.yaml").read_text())
    scen.update(seed=seed, duration=first_fire + 60.0)
    scen["trajectory"]["seed"] = seed
    scen["sensors"]["us"]["echo_prob"] = 0.05
    scen["sensors"]["us"]["first_fire_s"] = first_fire
    sp = tmp_path / "scen.yaml"
    sp.write_text(yaml.safe_dump(scen))
    log = tmp_path / "walk.log"
    assert main(["simulate", str(sp), "-o", str(log)]) == 0
    s = _cli(tmp_path, IEKF, "--input", str(log))
    assert s["errors"]["position_rmse_m"] < 0.08
    assert 1.0 < s["consistency"]["nees_mean"] < 6.0


def test_pose_config_on_its_recording(tmp_path):
    s = _cli(tmp_path, POSE)
    assert s["errors"]["position_rmse_m"] < 0.08
    assert s["errors"]["attitude_rmse_deg"] < 15.0


@pytest.mark.parametrize("config", [IEKF, POSE], ids=["iekf", "pose"])
def test_hostile_lines_are_counted_not_fatal(tmp_path, config):
    """Bad numbers, unknown beacons, NaN, a receiver out of range, short lines: each one clear event, the run
    goes on (exit 0), before and after the filter starts."""
    good = [ln for ln in (ROOT / "recordings" / "ultrasonic_3d_walk.log").read_text().splitlines()[:200]]
    bad = ["0.30,us,B2,abc,11", "0.31,us,B9,0.31,11", "0.32,us,B3,nan,4", "0.33,us,B3,0.33,0", "0.34,us,B4",
           "0.35,us,B4,0.35,2.5"]
    head = [ln for ln in good if ln.startswith("#")]
    body = [ln for ln in good if not ln.startswith("#")]
    log = tmp_path / "hostile.log"
    late = [b.replace("0.3", "30.3", 1) for b in bad]
    log.write_text("\n".join(head + bad + body[:150] + late + body[150:]) + "\n")
    s = _cli(tmp_path, config, "--input", str(log))
    assert s["sensors"]["us"]["used"] > 20


def test_geometric_solver_standalone_in_a_config(tmp_path):
    """tdoa_geometric as the preprocessor of a plain position filter (its fixes, with their covariance, as
    position measurements): one fix per cycle on the shipped walk, errors at the fix level (~80 mm per
    axis with 0.2 ms) and echoes unprotected, so only a loose bound."""
    cfg = tmp_path / "geo.yaml"
    cfg.write_text(f"""
name: geometric
recording: {ROOT / 'recordings' / 'ultrasonic_3d_walk.log'}
beacons: {{B1: [0, 0, 0], B2: [2.6, 0, 0], B3: [0, 2.6, 0], B4: [0, 0, 2.6]}}
process: {{type: pv, dims: 3, spectral_density: 0.001}}
initial: {{from_sensor: us, mean: {{v: [0, 0, 0]}}, sd: {{p: 1.0, v: 0.05}}}}
filter: ekf
sensors:
  us:
    preprocessor: {{type: tdoa_geometric, period_s: 0.225, speed_of_sound: 340.0, arrival_sd: 2.0e-4}}
    model: position
    gate: {{type: chi2, probability: 0.999}}
""")
    s = _cli(tmp_path, cfg)
    us = s["sensors"]["us"]
    assert 300 <= us["used"] + us["rejected"] <= 335          # one fix per cycle of four (1333 arrivals)
    assert s["errors"]["position_rmse_m"] < 0.15


# --------------------------------------------------------------------------- paper 003 Tables I-II: the sd
def _cases():
    import sys

    sys.path.insert(0, str(ROOT / "experiments"))
    import ultrasonic_3d_cases as uc

    return uc


@pytest.mark.parametrize("start", [(1.21, 1.15, 1.36), (2.37, 2.2, 1.35)], ids=["row1", "far"])
def test_stationary_iekf_reports_the_bound_of_its_arrivals(tmp_path, start):
    """A standing robot, no echoes, 30 cycles: the position IEKF with the paper's stationary model reports
    the Cramer-Rao bound of the arrivals it used (tdoa_geometric.stationary_bound), i.e. Table II's sd is
    fixed by the geometry, the noise and the number of arrivals. Used: every arrival but those the gate
    refused (the initial cycles enter through the initial fix)."""
    import numpy as np

    from fusion_plugins.solvers.tdoa_geometric import stationary_bound

    uc = _cases()
    truth = np.array(start)
    for seed in (1, 2):
        sc = uc.scenario("ultrasonic_3d_static", seed, duration=30 * 0.9 + 0.3, us__echo_prob=0.0,
                         trajectory__start=list(start))
        path = uc.write_log(sc, seed, str(tmp_path))
        log = uc.read_log(path)
        res = uc.run_system(uc.load(uc.IEKF, position_sd=0.0), path)
        B = np.array([sc.beacons[b] for b in log.beacon], float)
        fires = np.rint((log.arrival - log.arrival[0]) / 0.225)
        used = np.ones(len(log.t), bool)
        used[np.searchsorted(log.t, res["t"][1:][~res["accepted"][1:]])] = False
        bound = np.sqrt(np.diag(stationary_bound(B[used], truth, fires[used], 340.0, 2.0e-4))[:3])
        ratio = res["sd"][-1, :3] / bound
        assert np.all((ratio > 0.97) & (ratio < 1.08)), ratio   # the initial fix carries a little less


def test_initialiser_at_the_far_position_over_seeds(tmp_path):
    """Paper 003's far position (row 4) with the echoes of Tables I-II (11.7 %): over 12 seeds the initial
    fix of tdoa_geometric is never metres off, and its error fits its covariance (chi-square 99 % in at
    least 10 of 12; the seeds and echo rate of the results page, row 4). Before the agreement test used the
    better-determined fix's covariance, an echo thrown
    far (metres-wide covariance) agreed with good fixes and one seed in ten started 8 m off."""
    import numpy as np

    from fusion import testing
    from fusion.api import BuildContext, Fix, Message

    uc = _cases()
    from ultrasonic_3d_tables import ECHO_RATE

    truth = np.array([2.37, 2.2, 1.35])
    errs, fits = [], 0
    for seed in range(4000, 4012):
        sc = uc.scenario("ultrasonic_3d_static", seed, duration=64 * 0.9 + 0.3, us__echo_prob=ECHO_RATE,
                         trajectory__start=truth.tolist())
        path = uc.write_log(sc, seed, str(tmp_path))
        log = uc.read_log(path)
        s = testing.build("solver", "tdoa_geometric", {"output": "initialise"},
                          BuildContext(beacons={k: np.array(v, float) for k, v in sc.beacons.items()}, sensor="us"))
        fix = next(m for j in range(len(log.t))
                   for m in s.feed(Message(log.t[j], "us", (log.beacon[j], log.arrival[j], float(log.receiver[j]))))
                   if isinstance(m, Fix))
        p, C = fix.value[:3], fix.cov[:3, :3]
        e = p - truth
        errs.append(float(np.linalg.norm(e)))
        fits += float(e @ np.linalg.solve(C, e)) <= 11.34
    assert max(errs) < 1.0 and fits >= 10, (errs, fits)


@pytest.mark.parametrize("config", [IEKF, POSE])
def test_a_log_stamped_in_unix_time_gives_the_same_estimate(tmp_path, config):
    """Every time of the walk (stamps, arrival values, truth t_fire) shifted by 1.8e9 s, exactly in decimal:
    gated against the config's prior t 0 +- 1e5 s the geometric initial fix would be refused and the
    RMSE double. The initial fix replaces the prior ungated: the same numbers."""
    from decimal import Decimal

    lines = (ROOT / "recordings" / "ultrasonic_3d_walk.log").read_text().splitlines()[:1500]
    off, shifted = Decimal(1_800_000_000), []
    for ln in lines:
        if not ln.startswith("#"):
            p = ln.split(",")
            p[0] = str(Decimal(p[0]) + off)
            if p[1] == "us":
                p[3] = str(Decimal(p[3]) + off)
            if p[1] == "truth":
                p[-1] = str(Decimal(p[-1]) + off)
            ln = ",".join(p)
        shifted.append(ln)
    results = []
    for name, text in (("plain", lines), ("unix", shifted)):
        log = tmp_path / f"{name}.log"
        log.write_text("\n".join(text) + "\n")
        out = tmp_path / f"{name}.json"
        assert main(["run", str(config), "--input", str(log), "-q", "--summary-json", str(out)]) == 0
        results.append(json.loads(out.read_text()))
    plain, unix = results
    assert unix["sensors"]["us"] == plain["sensors"]["us"]
    assert unix["errors"]["position_rmse_m"] == pytest.approx(plain["errors"]["position_rmse_m"], rel=1e-3)
