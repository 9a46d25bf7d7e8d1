"""The smoothing study's Monte-Carlo over walks (issue 17, experiments/smoother_seeds.py): paper 003's
scenario fixes its random walk (trajectory.seed), so 50 seeds of it were 50 noise draws on one walk, and its
pose statistics those of one trajectory. The study now draws the walk with each run's seed: with the
scenario's own trajectory seed the recording is byte-identical to ``fusion simulate``'s, and two run seeds
give two different walks (the truth lines differ, not only the noise)."""
from __future__ import annotations

import sys
from pathlib import Path

import yaml

from fusion.simulate.engine import simulate_file

ROOT = Path(__file__).resolve().parents[2]
WALK = ROOT / "scenarios" / "ultrasonic_3d_walk.yaml"


def _study():
    sys.path.insert(0, str(ROOT / "experiments"))
    try:
        import smoother_seeds
    finally:
        sys.path.remove(str(ROOT / "experiments"))
    return smoother_seeds


def _truth(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ",truth," in ln]


def test_the_walk_scenario_is_the_study_s_random_walk_and_its_seed_draws_the_walk():
    study = _study()
    assert WALK.name in study.WALKS
    own = yaml.safe_load(WALK.read_text())["trajectory"]["seed"]
    assert study.walk_per_seed(WALK, own) == simulate_file(str(WALK), seed=own)
    a, b = study.walk_per_seed(WALK, 101), study.walk_per_seed(WALK, 102)
    fixed = simulate_file(str(WALK), seed=101)
    assert _truth(a) != _truth(b) and _truth(a) != _truth(fixed)
    assert _truth(simulate_file(str(WALK), seed=102)) == _truth(fixed)   # the scenario alone: one walk
