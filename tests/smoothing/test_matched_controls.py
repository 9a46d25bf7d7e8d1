"""A matched-model control, small (issue 17; the 50-seed version is experiments/smoother_seeds.py): the
UWB system of paper 001 (configs/uwb_pv_ukf.yaml, UKF and its RTS smoother) on truths drawn from its own
PV model (scenarios/controls/uwb_pv_matched.yaml: white acceleration of the config's 0.2 m^2/s^3, the initial state
from the config's prior, 0.1 m ranges), a new walk each seed. On its own model the filter and the smoother
must be consistent: the mean NEES over the seeds near its 4 dof (the shipped routes, a mismatched truth,
give ~2.3; a smoother that kept the filtered covariance, or shrank it too far, leaves these bounds), most
samples inside their 95% interval, and the smoothed error below the filtered one on every seed."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fusion.config import load_system
from fusion.simulate.engine import simulate
from fusion.simulate.scenario import load_scenario
from fusion.smoothing import run_smoothed

ROOT = Path(__file__).resolve().parents[2]
SEEDS = range(1, 7)   # 6 walks of 15 s (~0.3 s each)


def _recording(seed: int, walls: bool) -> list[str]:
    sc, text = load_scenario(ROOT / "scenarios" / "controls" / "uwb_pv_matched.yaml")
    upd = {"seed": seed} if walls else {"seed": seed, "bounds": None}
    sc = sc.model_copy(update={"trajectory": sc.trajectory.model_copy(update=upd)})
    return simulate(sc, seed=seed, text=text).splitlines()


@pytest.mark.parametrize("walls", [True, False], ids=["in the hall", "no walls"])
def test_pv_filter_and_smoother_are_consistent_on_their_own_model(walls):
    system = load_system(ROOT / "configs" / "uwb_pv_ukf.yaml")
    runs = [run_smoothed(system, _recording(s, walls)).summary for s in SEEDS]
    f = np.array([r["consistency"]["nees_mean"] for r in runs])
    sm = np.array([r["smoothed"]["consistency"]["nees_mean"] for r in runs])
    assert all(r["consistency"]["nees_dof"] == 4 for r in runs)
    # one run's mean NEES spreads ~0.5 about 4 here: the mean of 6 is good to ~0.2; +-0.8 is 4 of those
    assert 3.2 < f.mean() < 4.8, f
    assert 3.2 < sm.mean() < 4.8, sm
    assert np.mean([r["smoothed"]["consistency"]["nees_in_95_fraction"] for r in runs]) > 0.88
    rf = np.array([r["errors"]["position_rmse_m"] for r in runs])
    rs = np.array([r["smoothed"]["errors"]["position_rmse_m"] for r in runs])
    assert np.all(rs < rf), (rf, rs)
