"""The initial position from the fixes of a static alignment window (tester5 #7) and the alignment's
stillness test (tester5 #5).

#7: the initial position was the LAST fix of ``initial.align_s`` (docs: "the first fix"): one echo-corrupted
fix there started the filter 1.6 m off. Now a window judged static combines its fixes robustly
(fusion.run.startup.combine_fixes). #5: the window was averaged as static with no check; a
moving one is now a warning (and the summary's health), the gyro-bias prior is kept."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from fusion.api import Observation
from fusion.config import load_system
from fusion.run import Loop
from fusion.run.startup import combine_fixes

ROOT = Path(__file__).resolve().parents[2]


def test_combine_refuses_an_outlier_and_keeps_one_fix_covariance():
    rng = np.random.default_rng(3)
    R = np.diag([0.05, 0.2, 0.05]) ** 2
    zs = rng.multivariate_normal([3.0, 1.2, -0.75], R, size=19)
    zs[-1] += [0.0, 1.6, 0.0]                            # an echo, last in the window
    z, P, keep = combine_fixes(zs, np.repeat(R[None], 19, axis=0))
    assert not keep[-1] and keep[:-1].all()
    assert np.linalg.norm(z[:2] - [3.0, 1.2]) < 0.1
    np.testing.assert_allclose(P, R, atol=1e-15)         # fully correlated bound: one fix's R, not R / 19


def test_combine_keeps_an_averaged_fix_its_own_claim():
    R = np.eye(3) * 4.0
    zs = np.array([[0.0, 0.0, 0.0], [1.0, -1.0, 0.5]])
    z, P, keep = combine_fixes(zs, np.array([R / 39.0, R]))   # an origin fix of 39 (R / N) and a raw fix
    assert keep.all()
    assert np.all(np.diag(P) <= 4.0 / 30.0) and np.all(np.diag(P) >= 4.0 / 39.0)
    np.testing.assert_allclose(z, zs[1] / 40.0)


def test_combine_without_covariances_is_the_median():
    zs = np.array([[0.0, 0.0], [0.1, 0.2], [5.0, -3.0]])
    z, P, keep = combine_fixes(zs, None)
    np.testing.assert_allclose(z, [0.1, 0.0])
    assert P is None


def _abps_scheduler() -> Loop:
    return Loop(load_system(ROOT / "configs" / "abps_ins.yaml"))


def _fixes(sched: Loop, last_off: float) -> None:
    model = sched.sensors["abps"].model
    R = np.diag([0.07, 0.22, 0.05]) ** 2
    rng = np.random.default_rng(1)
    for i in range(19):
        z = np.array([3.2, 1.2, -0.75]) + rng.normal(size=3) * [0.07, 0.22, 0.05]
        if i == 18:
            z[1] += last_off
        sched.startup.take_fix(Observation(0.45 * i, z, model, R))


def test_static_window_starts_from_the_fixes_not_the_last_one():
    sched = _abps_scheduler()
    _fixes(sched, 1.6)
    sched.startup.still = True                                  # the alignment found the window static
    x0, P0 = sched.startup.initial()
    p = sched.system.layout["p"]
    rx = x0[p.start:p.start + 2] + [0.2, 0.0]             # the receiver (lever arm 0.2 m forward, yaw 0)
    assert np.linalg.norm(rx - [3.2, 1.2]) < 0.15         # the last fix alone: 1.6 m off
    assert P0[p.start + 1, p.start + 1] == pytest.approx(0.22 ** 2)
    assert any(e.kind == "initial" and "18 of the 19" in e.detail for e in sched.tally.take())


def test_a_window_not_judged_static_starts_from_the_latest_fix():
    sched = _abps_scheduler()
    _fixes(sched, 1.6)
    sched.startup.still = None                                  # no stillness verdict (no test, in flight)
    x0, _ = sched.startup.initial()
    p = sched.system.layout["p"]
    assert x0[p.start + 1] > 2.2


def _run(tmp_path: Path, static_start: float):
    """The shipped ABPS config on a ~25 s drive of the mine scenario whose static start is ``static_start`` s
    (0.5: the vehicle drives, and bends, inside the 9 s alignment window)."""
    from fusion import pipeline
    from fusion.simulate import simulate_file

    sc = yaml.safe_load((ROOT / "scenarios" / "abps_mine.yaml").read_text())
    sc["trajectory"]["static_start"] = static_start
    sc["trajectory"]["waypoints"] = sc["trajectory"]["waypoints"][:4]
    sc["seed"] = 2
    scenario = tmp_path / "sc.yaml"
    scenario.write_text(yaml.safe_dump(sc))
    log = tmp_path / "rec.log"
    log.write_text(simulate_file(str(scenario)))
    events = []
    result = pipeline.run(load_system(ROOT / "configs" / "abps_ins.yaml"), str(log), on_event=events.append)
    return result, events


def test_a_moving_start_is_told_and_its_mean_rate_not_taken_as_bias(tmp_path):
    result, events = _run(tmp_path, 0.5)
    warned = [e for e in events if e.kind == "warning" and "alignment" in e.detail]
    assert len(warned) == 1 and "not static" in warned[0].detail and " sd " in warned[0].detail
    assert "IMU samples" in result.summary["health"]["alignment_not_static"]
    assert result.summary["errors"]["position_rmse_m"] < 0.2          # before: ~0.8 m (tester5 #5)
    assert result.summary["errors"]["attitude_max_deg"] < 10.0        # before: ~40 deg


def test_a_static_start_is_no_false_alarm(tmp_path):
    result, events = _run(tmp_path, 10.0)
    assert not [e for e in events if e.kind == "warning" and "alignment" in e.detail]
    assert "alignment_not_static" not in result.summary["health"]
    assert any(e.kind == "initial" for e in events)
