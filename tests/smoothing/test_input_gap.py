"""The smoother across an input gap: a prediction that holds one IMU sample longer than the input sensor's
``max_gap`` breaks the chain (G = 0), as a recovery reset does, so what comes after the gap cannot corrupt
the smoothed estimates before it.

The case: configs/imu_gps_mag_ekf.yaml on the shipped car recording with a pause of
every stream during the first corner (80 <= t < 85 s, the car turning at ~0.3 rad/s). The INS predicts the
pause by holding the last IMU sample (``hold_after``, hold noise); the linearised transition over those 5 s
kept one direction of the attitude noise-free, and the backward pass carried the attitude correction after
the pause back onto the estimates before it: over 70-80 s the smoothed attitude was 26 deg off (NEES of p, v
2300 on 6 dof) where the filter's was 0.3 deg."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fusion import pipeline, testing
from fusion.testing.faults import cut_recording
from fusion.api import Estimate
from fusion.config import load_system
from fusion.smoothing import run_smoothed
from fusion.smoothing.backward import smooth, smoothed_estimates
from fusion.smoothing.record import ForwardLog, RecordingFilter
from fusion.smoothing.store import ChunkStore
from fusion_plugins.filters.rts import backend_for

from smoothing_models import Unicycle

ROOT = Path(__file__).resolve().parents[2]
PAUSE, LENGTH, END = 80.0, 5.0, 95.0      # s
BEFORE = (70.0, PAUSE)                     # s: the window scored before the pause


def _lines(imu_only: bool = False, end: float = END):
    """The car config and its recording up to ``end`` s without the lines of the pause (every stream, or
    with ``imu_only`` the IMU alone: the others go on)."""
    system = load_system(ROOT / "configs" / "imu_gps_mag_ekf.yaml")
    return system, cut_recording(system.recording, lambda t, ln: PAUSE <= t < PAUSE + LENGTH
                                 and (not imu_only or ",imu," in ln), end=end)


@pytest.fixture(scope="module")
def truth():
    rows = {}
    with open(ROOT / "recordings" / "car_gps_mag.log") as fh:
        for ln in fh:
            if ",truth," in ln:
                p = ln.split(",")
                rows[round(float(p[0]), 3)] = np.array([float(v) for v in p[2:12]])
    return rows


def _score(ests, truth) -> tuple[float, float]:
    """(attitude RMSE deg, mean NEES of p, v on 6 dof) of the estimates in BEFORE with a truth row."""
    att, nees = [], []
    for e in ests:
        x = truth.get(round(e.t, 3))
        if x is None or not BEFORE[0] <= e.t < BEFORE[1]:
            continue
        att.append(np.degrees(2.0 * np.arccos(min(1.0, abs(e.belief.x[6:10] @ x[6:10])))))
        err = e.belief.x[:6] - x[:6]
        nees.append(err @ np.linalg.solve(e.belief.cov[:6, :6], err))
    assert len(att) > 20
    return float(np.sqrt(np.mean(np.square(att)))), float(np.mean(nees))


def _before(ests):
    return [e for e in ests if e.t < PAUSE]


@pytest.fixture(scope="module")
def paused():
    system, lines = _lines()
    filtered, full, lagged = pipeline.Collect(), pipeline.Collect(), pipeline.Collect()
    pipeline.run(system, lines, [filtered])
    res = run_smoothed(system, lines, [full])
    res_lag = run_smoothed(system, lines, [lagged], lag=1.0e6)
    return filtered.estimates, full.estimates, lagged.estimates, res.summary, res_lag.summary


def test_smoothed_before_a_pause_is_not_corrupted_by_it(paused, truth):
    filtered, full, _, summary, _ = paused
    att_f, nees_f = _score(filtered, truth)
    att_s, nees_s = _score(full, truth)
    assert att_f < 0.5 and nees_f < 6.0                 # the filter is good there
    assert att_s < att_f + 0.1                           # a chain unbroken at the gap: 26 deg
    assert nees_s < 6.0                                  # within its covariance; unbroken: 2300
    assert summary["smoothed"]["breaks"] == 1 and summary["smoothed"]["input_gap_breaks"] == 1


def test_before_a_pause_the_smoother_is_the_one_of_the_recording_cut_there(paused):
    """G = 0 across the pause: before it, the smoothed estimates are those of the recording cut at the
    pause (nothing after it flows back)."""
    _, full, _, _, _ = paused
    system, lines = _lines(end=PAUSE - 1e-6)
    cut = pipeline.Collect()
    run_smoothed(system, lines, [cut])
    a, b = _before(full), cut.estimates
    assert [e.t for e in a] == [e.t for e in b] and len(a) > 100
    assert np.abs(np.array([e.belief.x for e in a]) - np.array([e.belief.x for e in b])).max() < 1e-9
    assert np.abs(np.array([e.belief.sd for e in a]) - np.array([e.belief.sd for e in b])).max() < 1e-9


def test_fixed_lag_longer_than_the_run_is_the_full_smoother_across_a_pause(paused):
    _, full, lagged, summary, summary_lag = paused
    assert [e.t for e in lagged] == [e.t for e in full]
    assert np.abs(np.array([e.belief.x for e in lagged]) - np.array([e.belief.x for e in full])).max() < 1e-9
    assert np.abs(np.array([e.belief.sd for e in lagged]) - np.array([e.belief.sd for e in full])).max() < 1e-9
    assert summary_lag["smoothed"]["errors"] == summary["smoothed"]["errors"]
    assert summary_lag["smoothed"]["input_gap_breaks"] == 1


def test_imu_silent_while_the_others_go_on(truth):
    """The hold cut into many predictions by the fixes and magnetometer samples of the gap: every one
    past max_gap breaks the chain; before the gap the smoothed estimate stays good."""
    system, lines = _lines(imu_only=True)
    filtered, sm = pipeline.Collect(), pipeline.Collect()
    pipeline.run(system, lines, [filtered])
    res = run_smoothed(system, lines, [sm])
    s = res.summary["smoothed"]
    # every break an input gap's, or a recovery reset of the filter (the config's gps recovery may fire
    # while the IMU is silent)
    assert s["input_gap_breaks"] >= 20 and s["breaks"] == s["input_gap_breaks"] + res.summary["health"]["resets"]
    att_f, _ = _score(filtered.estimates, truth)
    att_s, nees_s = _score(sm.estimates, truth)
    assert att_s < att_f + 0.1 and nees_s < 6.0


BEACONS = [[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0]]


def _unicycle_run(predictions, max_hold):
    """Record the EKF on the unicycle: each of ``predictions`` (``predict`` (u, dt) or ``inputs`` (us,
    dts)) followed by a range update, an estimate noted after each update. Returns (log, filtered,
    smoothed) beliefs at the estimates: estimate i is the node closed by prediction i + 1."""
    rng = np.random.default_rng(7)
    flt = testing.build("filter", "ekf")
    meas = testing.RangeMeasurement(testing.RangeMeasurement.Params(beacons=BEACONS, n=3))
    log = ForwardLog(backend_for(flt), 3, max_hold=max_hold)
    rec = RecordingFilter(flt, log)
    process = Unicycle()
    b = rec.initial_belief(0.0, np.array([3.0, 2.0, 0.3]), np.diag([0.1, 0.1, 0.05]))
    filtered = []
    for kind, args in predictions:
        b = rec.predict(b, process, *args) if kind == "predict" else rec.predict_inputs(b, process, *args)
        b = rec.update(b, meas, meas.h(b.x[:2]) + rng.normal(0.0, 0.1, 4), np.eye(4) * 0.01).belief
        filtered.append(b)
        log.note_estimate(Estimate(b.t, b, "update"))
    out = ChunkStore()
    smooth(log, process.normalize, np.subtract, out)
    return log, filtered, [e.belief for e in smoothed_estimates(out, False, log.sensors)]


def test_a_hold_is_timed_across_predictions_and_new_samples_start_afresh():
    u1, u2 = np.array([1.0, 0.2]), np.array([1.0, 0.2])      # two samples with the same values
    u3 = np.array([2.0, -0.1])
    predictions = [
        ("inputs", (np.array([u1, u2]), np.array([0.05, 0.05]))),   # u2 a new sample: held 0.05 s
        ("predict", (u2, 0.04)),                                    # held 0.09 s
        ("predict", (u2, 0.03)),                                    # 0.12 s > 0.1: breaks
        ("inputs", (np.array([u2, u3]), np.array([0.01, 0.08]))),   # u2 at 0.13 s: breaks again
        ("predict", (u3, 0.01)),                                    # u3 at 0.09 s: kept
        ("predict", (u3, 0.005)),
    ]
    log, filtered, smoothed = _unicycle_run(predictions, max_hold=0.1)
    assert log.gap_breaks == 2 and log.breaks == 2
    for i in range(len(filtered) - 1):
        same = np.array_equal(smoothed[i].x, filtered[i].x) and np.array_equal(smoothed[i].P, filtered[i].P)
        assert same == (i in (1, 2)), i       # closed by predictions 2 and 3: the breaks
    log, filtered, smoothed = _unicycle_run(predictions, max_hold=None)
    assert log.breaks == 0
    assert all(not np.array_equal(smoothed[i].P, filtered[i].P) for i in range(len(filtered) - 1))
