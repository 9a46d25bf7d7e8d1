"""The health rule on hand-made summaries and update streams (fusion.health.rule, fusion.health.watch):
each limit at its edge, and the causes' order."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from fusion.api import Estimate, UpdateResult
from fusion.health import HealthSpec, HealthWatch, judge
from fusion.health.causes import RunContext, SensorContext
from fusion.recovery import RecoverySpec

CTX = RunContext(max_latency=0.1, header_read=True,
                 sensors={"gps": SensorContext("gps", model="gps", time_offset=-0.3, gate="chi2"),
                          "mag": SensorContext("mag", header=("mag earth_field_ned: 1 2 3",))})


def _counts(**kw):
    c = dict(received=0, used=0, rejected=0, malformed=0, late=0, absorbed=0)
    c.update(kw)
    return c


def test_shares_at_the_limit():
    """Half the updates rejected is not over 0.5; one more is. A late share and a rejected share combine as
    1 - (1 - late)(1 - rejected): 30 % late and 30 % of the rest rejected is 51 % unused."""
    ok = {"sensors": {"gps": _counts(received=100, used=50, rejected=50)}}
    assert not judge(ok, ctx=CTX).degraded
    bad = {"sensors": {"gps": _counts(received=100, used=49, rejected=51)}}
    v = judge(bad, ctx=CTX)
    assert v.degraded and v.findings[0].kind == "shut_out" and "51 of 100 updates rejected (51 %)" in v.line()
    mixed = {"sensors": {"gps": _counts(received=100, late=30, used=49, rejected=21)}}
    assert judge(mixed, ctx=CTX).findings[0].figures.startswith("30 of 100 messages dropped as late")


def test_late_drops_put_the_latency_first_and_rejections_the_constants():
    late = judge({"sensors": {"gps": _counts(received=100, late=90, used=10)}}, ctx=CTX).findings[0]
    assert late.causes[0].startswith("a latency (sensors.gps.time_offset -0.3 s against scheduler.max_latency 0.1 s")
    rej = judge({"sensors": {"mag": _counts(received=100, used=10, rejected=90)}}, ctx=CTX).findings[0]
    assert rej.causes[0].startswith("the config's constants against the recording's header")
    assert "mag earth_field_ned: 1 2 3" in rej.causes[0]
    assert [c.split(" (")[0] for c in rej.causes[1:]] == ["a latency", "a gate too tight", "a missing recovery"]
    unread = RunContext(sensors=CTX.sensors)   # stdin or a port: the header's lines were not read
    first = judge({"sensors": {"mag": _counts(received=100, used=10, rejected=90)}}, ctx=unread).findings[0].causes[0]
    assert "the header:" not in first and "beacons" not in first


def test_absorbed_messages_are_not_unused_and_few_messages_are_not_judged():
    """A solver's ranges combined into one fix (absorbed) are used; 4 rejected of 4 is below min_messages."""
    absorbed = {"sensors": {"gps": _counts(received=400, used=90, rejected=10, absorbed=300)}}
    assert not judge(absorbed, ctx=CTX).degraded
    assert not judge({"sensors": {"gps": _counts(received=4, rejected=4)}}, ctx=CTX).degraded


def _system(recovery=None):
    sensor = SimpleNamespace(role="measurement", recovery=recovery)
    return SimpleNamespace(sensors={"gps": sensor, "imu": SimpleNamespace(role="input", recovery=None)})


def _feed(watch, times, accepted, nis=1.0, dof=1):
    for t, ok in zip(times, accepted):
        up = UpdateResult(None, np.zeros(dof), np.eye(dof), nis, ok)
        watch.on_estimate(Estimate(float(t), None, "update", "gps", up))


def test_lockout_to_the_end_without_recovery_and_past_the_recovery_with_one():
    """Without a recovery, rejections that last to the sensor's last update for 2 s and more are a lock-out,
    a stretch of them in the middle (a disturbance the gate kept out) is not; with a recovery of after_s 1 s
    a stretch longer than 1 s is."""
    t = np.arange(0.0, 20.0, 0.1)
    middle = (t < 8) | (t > 10)          # 2 s of rejections in the middle, 10 % of the span
    tail = t < 17.5                      # 2.4 s of rejections to the end
    w = HealthWatch(_system())
    _feed(w, t, middle)
    assert not judge({"sensors": {}}, w.report(), ctx=CTX).degraded
    w = HealthWatch(_system())
    _feed(w, t, tail)
    f = judge({"sensors": {}}, w.report(), ctx=CTX).findings
    assert f and f[0].kind == "locked_out" and "to its last update" in f[0].figures
    w = HealthWatch(_system(RecoverySpec(after_s=1.0)))
    _feed(w, t, middle)
    f = judge({"sensors": {}}, w.report(), ctx=CTX).findings
    assert f and "limit 1 s: sensors.gps.recovery.after_s" in f[0].figures
    assert "input" not in w.report()   # input sensors are not watched


def test_nis_windows_from_the_watch():
    """The watch sums accepted NIS over windows of nis_window_dof dof (rejected updates are left out); a
    consistent stream is healthy, one with NIS 3 per dof is not."""
    spec = HealthSpec(nis_window_dof=50)
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 100.0, 0.1)
    for scale, bad in ((1.0, False), (3.0, True)):
        w = HealthWatch(_system(), spec)
        for ti, v in zip(t, scale * rng.chisquare(1, t.size)):
            _feed(w, [ti], [True], nis=float(v))
        _feed(w, [100.0], [False], nis=1e6)
        rep = w.report()["gps"]
        assert len(rep["windows"]) == 20 and all(d == 50 for *_, d in rep["windows"])
        assert judge({"sensors": {}}, w.report(), spec, CTX).degraded is bad


def test_truth_and_reference_limits():
    s = {"sensors": {}, "errors": {"position_rmse_m": 2.0}, "consistency": {"nees_mean": 40.0, "nees_dof": 4},
         "agreement": {"attitude_rmse_deg": 29.0}}
    assert not judge(s, ctx=CTX).degraded                      # NEES 10 per dof is at the limit, 29 deg under 30
    s["consistency"]["nees_mean"] = 41.0
    assert judge(s, ctx=CTX).findings[0].kind == "truth"
    s["consistency"]["nees_in_95_fraction"] = 0.9   # a mean made by a few samples (a bad truth line): not persistent
    assert not judge(s, ctx=CTX).degraded
    s["consistency"]["nees_in_95_fraction"] = 0.3
    assert "30 % inside its 95 % interval" in judge(s, ctx=CTX).findings[0].figures
    s["consistency"]["nees_mean"] = 4.0
    s["agreement"]["attitude_rmse_deg"] = 128.0
    f = judge(s, ctx=CTX).findings
    assert [x.kind for x in f] == ["reference"] and "attitude RMSE 128 deg > 30" in f[0].figures
    spec = HealthSpec(truth={"position_rmse_m": 1.5})
    assert spec.truth.nees_per_dof == 10.0                     # a limit set keeps the other defaults
    assert {x.kind for x in judge(s, spec=spec, ctx=CTX).findings} == {"truth", "reference"}


def test_batch_watch_keeps_what_one_watch_a_trial_keeps():
    """fusion.health.batch_watch on N trials at once against N HealthWatch fed the same updates: the same
    reports (windows, runs of rejections, lock-outs, tails), trial by trial."""
    from fusion.health.batch_watch import BatchHealthWatch

    rng = np.random.default_rng(11)
    n, spec = 6, HealthSpec(nis_window_dof=30)
    system = _system(RecoverySpec(after_s=0.5))
    batch = BatchHealthWatch(system, n, spec)
    singles = [HealthWatch(system, spec) for _ in range(n)]
    for t in np.arange(0.0, 60.0, 0.1):
        dof = int(rng.integers(1, 4))
        accepted = rng.random(n) > (0.9 if 20 < t < 23 else 0.1)   # a stretch of rejections mid-run
        nis = rng.chisquare(dof, n)
        nis[rng.random(n) < 0.01] = np.nan
        batch.add("gps", t, accepted, nis, dof)
        for i, w in enumerate(singles):
            up = UpdateResult(None, np.zeros(dof), np.eye(dof), float(nis[i]), bool(accepted[i]))
            w.on_estimate(Estimate(float(t), None, "update", "gps", up))
    for i, w in enumerate(singles):
        one, many = w.report()["gps"], batch.report(i)["gps"]
        assert repr(one) == repr(many)   # repr: NaN (a run not started) compares equal to itself
        assert one["windows"] and one["lockouts"]
