"""The run loop (fusion.run.loop.Loop): reorder buffer, rates, late policies, outputs, input integration."""
import random
import textwrap

import numpy as np
import pytest

from fusion.api import Estimate, Event, Message
from fusion.config import SystemSpec, wire
from fusion.run import Loop, Updated

import yaml

BEACONS = {"B1": [0.0, 0.0], "B2": [20.0, 0.0], "B3": [20.0, 20.0], "B4": [0.0, 20.0]}


def system(max_latency=0.0, late_policy="drop", filt="ekf", rate_hz=None, offset=0.0):
    spec = SystemSpec.model_validate(yaml.safe_load(textwrap.dedent(f"""
        name: sched
        beacons: {BEACONS}
        process: {{type: pv, dims: 2, spectral_density: 0.2}}
        initial: {{mean: {{p: [5, 5], v: [0, 0]}}, sd: {{p: 3.0, v: 1.0}}}}
        filter: {filt}
        sensors:
          fast: {{model: {{type: range, beacons: [B1, B2]}}, noise: {{sd: 0.1}}, time_offset: {offset}}}
          slow: {{model: {{type: range, beacons: [B3, B4]}}, noise: {{sd: 0.2}}}}
        scheduler: {{max_latency: {max_latency}, late_policy: {late_policy}}}
        output: {{rate_hz: {rate_hz if rate_hz else 'null'}}}
    """)))
    return wire(spec)


def stream(seed=1, duration=20.0):
    """Ranges at 10 Hz (fast, alternating B1/B2) and 3 Hz (slow, B3/B4) from a circular walk."""
    rng = np.random.default_rng(seed)
    msgs = []
    def pos(t):
        return np.array([10 + 5 * np.cos(0.2 * t), 10 + 5 * np.sin(0.2 * t)])
    for k, t in enumerate(np.arange(0.05, duration, 0.1)):
        b = ["B1", "B2"][k % 2]
        msgs.append(Message(float(t), "fast", (b, float(np.linalg.norm(pos(t) - BEACONS[b]) + 0.1 * rng.normal()))))
    for k, t in enumerate(np.arange(0.0, duration, 1 / 3)):
        b = ["B3", "B4"][k % 2]
        msgs.append(Message(float(t), "slow", (b, float(np.linalg.norm(pos(t) - BEACONS[b]) + 0.2 * rng.normal()))))
    msgs.sort(key=lambda m: m.t)
    return msgs


def estimates(sched, msgs):
    return [e for e in sched.run(msgs) if isinstance(e, Estimate)]


def test_shuffled_arrival_gives_same_estimates_as_time_order():
    msgs = stream()
    ref = estimates(Loop(system()), msgs)
    rng = random.Random(7)
    # Jitter arrival order by up to 0.4 s; a 0.5 s reorder buffer restores the time order.
    arrival = sorted(msgs, key=lambda m: m.t + rng.uniform(0, 0.4))
    assert arrival != msgs
    got = estimates(Loop(system(max_latency=0.5)), arrival)
    assert len(got) == len(ref) == len(msgs)
    for a, b in zip(got, ref):
        assert a.t == b.t and a.sensor == b.sensor
        np.testing.assert_allclose(a.belief.x, b.belief.x, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.belief.cov, b.belief.cov, rtol=0, atol=1e-12)


def test_late_messages_dropped_and_counted():
    msgs = stream()
    rng = random.Random(3)
    arrival = sorted(msgs, key=lambda m: m.t + rng.uniform(0, 0.4))
    sys_ = system(max_latency=0.0)
    sched = Loop(sys_)
    out = list(sched.run(arrival))
    late = sum(s.counters["late"] for s in sched.sensors.values())
    assert late > 0
    assert late == sum(1 for e in out if isinstance(e, Event) and e.kind == "late")
    # A message arriving ahead of the others by more than the cadence bound is held (fusion.run.clock) and, when
    # its sensor's next message comes stamped before it, dropped as a wild stamp: counted, with a time event.
    wild = sum(s.counters["malformed"] for s in sched.sensors.values())
    assert wild == sum(1 for e in out if isinstance(e, Event) and e.kind == "time")
    assert sum(1 for e in out if isinstance(e, Estimate)) == len(msgs) - late - wild


def test_replay_recovers_time_ordered_result():
    msgs = stream(duration=10.0)
    ref = estimates(Loop(system()), msgs)
    # Hold back three messages and deliver them 1 s late: replay must give the same final belief.
    held = {5, 17, 40}
    arrival = [m for i, m in enumerate(msgs) if i not in held]
    for i in sorted(held):
        pos = next(j for j, m in enumerate(arrival) if m.t > msgs[i].t + 1.0)
        arrival.insert(pos, msgs[i])
    sys_ = system(late_policy="replay")
    sched = Loop(sys_)
    out = list(sched.run(arrival))
    # replayed, so counted by what the re-run made of them (used), not late
    assert sum(1 for e in out if isinstance(e, Event) and e.kind == "replayed") == 3
    assert sum(s.counters["late"] for s in sched.sensors.values()) == 0
    assert sum(s.counters["used"] for s in sched.sensors.values()) == len(msgs)
    np.testing.assert_allclose(sched.belief.x, ref[-1].belief.x, atol=1e-10)
    np.testing.assert_allclose(sched.belief.cov, ref[-1].belief.cov, atol=1e-10)


@pytest.mark.parametrize("seed", range(5))
def test_replay_of_consecutive_and_jittered_late_messages_recovers_the_time_ordered_result(seed):
    """Every message up to 0.35 s late (most of them behind an earlier late one): each is replayed from a
    snapshot before it, none dropped while the history covers it, and the end is the in-order belief.
    (Not in the first second: a message older than the filter's first one has no snapshot before it.)"""
    msgs = stream(seed=seed, duration=10.0)
    ref = estimates(Loop(system()), msgs)
    rng = random.Random(seed)
    arrival = sorted(msgs, key=lambda m: m.t + (rng.uniform(0, 0.35) if m.t > 1.0 else 0.0))
    sched = Loop(system(late_policy="replay"))
    out = list(sched.run(arrival))
    replayed = sum(1 for e in out if isinstance(e, Event) and e.kind == "replayed")
    assert replayed > 20 and sum(s.counters["late"] for s in sched.sensors.values()) == 0
    assert not any(isinstance(e, Event) and e.kind == "late" for e in out)
    assert sum(s.counters["used"] for s in sched.sensors.values()) == len(msgs)
    np.testing.assert_allclose(sched.belief.x, ref[-1].belief.x, rtol=0, atol=1e-10)
    np.testing.assert_allclose(sched.belief.cov, ref[-1].belief.cov, rtol=0, atol=1e-10)


def test_two_adjacent_late_messages_are_both_replayed():
    """The second of two consecutive late ranges is older than the first one's re-run: still replayed."""
    msgs = stream(duration=6.0)
    ref = estimates(Loop(system()), msgs)
    a, b = 20, 21
    arrival = [m for i, m in enumerate(msgs) if i not in (a, b)]
    for i in (a, b):
        pos = next(j for j, m in enumerate(arrival) if m.t > msgs[b].t + 0.3)
        arrival.insert(pos, msgs[i])
    sched = Loop(system(late_policy="replay"))
    out = list(sched.run(arrival))
    assert [e.kind for e in out if isinstance(e, Event) and e.kind in ("late", "replayed")] == ["replayed"] * 2
    np.testing.assert_allclose(sched.belief.x, ref[-1].belief.x, rtol=0, atol=1e-10)


def test_fixed_rate_outputs_between_updates():
    msgs = stream(duration=5.0)
    out = estimates(Loop(system(rate_hz=20)), msgs)
    ticks = [e.t for e in out if e.reason == "output"]
    assert len(ticks) >= 5 * 20 - 2
    np.testing.assert_allclose(np.diff(ticks), 0.05, atol=1e-9)


def test_time_offset_shifts_sensor_time():
    msgs = stream(duration=3.0)
    out = estimates(Loop(system(offset=-0.02, max_latency=0.02)), msgs)   # the offset fits the buffer
    fast_t = sorted(e.t for e in out if e.sensor == "fast")
    np.testing.assert_allclose(fast_t[:3], [0.03, 0.13, 0.23], atol=1e-12)


def test_truth_and_unknown_sensors_are_not_fed():
    msgs = [Message(0.0, "truth", (1.0, 2.0, 0.0, 0.0)), Message(0.1, "mystery", (1.0,))] + stream(duration=1.0)
    sched = Loop(system())
    out = list(sched.run(msgs))
    assert sched.unused == {"mystery": 1}                  # truth is the pipeline's, never counted as unknown
    assert any(isinstance(e, Event) and e.kind == "warning" and e.sensor == "mystery" for e in out)


def test_message_with_several_ranges_uses_block_diagonal_R():
    """One message 'B1 r1 B2 r2' is one joint EKF update with R = 0.1^2 I (R of the config is per range)."""
    sys_ = system()
    a = estimates(Loop(sys_), [Message(0.0, "fast", ("B1", 9.0, "B2", 12.0))])[-1]
    x, P = sys_.x0, sys_.P0
    b = np.array([BEACONS["B1"], BEACONS["B2"]])
    d = x[:2] - b
    r = np.linalg.norm(d, axis=1)
    H = np.zeros((2, 4))
    H[:, :2] = d / r[:, None]
    S = H @ P @ H.T + 0.01 * np.eye(2)
    K = P @ H.T @ np.linalg.inv(S)
    np.testing.assert_allclose(a.update.S, S, atol=1e-12)
    np.testing.assert_allclose(a.belief.x, x + K @ (np.array([9.0, 12.0]) - r), atol=1e-12)


def test_geometry_warning_reported_when_it_starts_and_clears():
    """Collinear beacons: walking up to the beacons' line starts a warning (once), walking away clears it."""
    spec = SystemSpec.model_validate({
        "name": "line", "beacons": {"A": [0.0, 0.0], "B": [10.0, 0.0], "C": [20.0, 0.0]},
        "process": {"type": "pv", "dims": 2, "spectral_density": 0.1}, "filter": "ukf",
        "initial": {"mean": {"p": [5.0, 8.0], "v": [0.0, -1.0]}, "sd": {"p": 0.5, "v": 0.2}},
        "sensors": {"uwb": {"model": "range", "noise": 0.05}}})
    msgs = []
    for k in range(120):  # 12 s: y goes 8 -> 0.05 (onto the line) and back out to ~8
        t = 0.1 * k
        y = max(8.0 - 1.6 * t, 0.05) if t < 7.0 else 0.05 + (t - 7.0) * 1.6
        p = np.array([5.0, y])
        b = "ABC"[k % 3]
        msgs.append(Message(t, "uwb", (b, float(np.linalg.norm(p - np.array(spec.beacons[b]))))))
    out = list(Loop(wire(spec)).run(msgs))
    kinds = [e.kind for e in out if isinstance(e, Event) and e.sensor == "uwb"]
    assert "warning" in kinds and "cleared" in kinds
    first_warn = next(i for i, k in enumerate(kinds) if k == "warning")
    assert kinds.index("cleared") > first_warn
    assert kinds.count("cleared") <= kinds.count("warning") <= 3


def test_a_replayed_message_is_counted_once_by_its_re_run_outcome():
    """late_policy: replay: a late message the gate rejects in the re-run is counted rejected (with its event),
    one it takes used, never also late, and its NIS goes to the statistics: the counts and the NIS samples are
    those of the time-ordered run (they were: every late message used and late, rejections lost, no NIS)."""
    msgs = stream(duration=10.0)
    for i, m in enumerate(msgs):   # every 4th fast range an outlier
        if m.sensor == "fast" and i % 4 == 0 and m.t > 1.0:
            msgs[i] = m._replace(values=(m.values[0], m.values[1] + 5.0))

    def run(sched, arrival):
        out = [o for m in arrival for o in sched.push(m)] + list(sched.finish())
        nis = [(u.sensor, round(u.t, 9), u.accepted) for u in out if isinstance(u, Updated)]
        assert nis   # the NIS travels in the loop's output
        return [o for o in out if not isinstance(o, Updated)], sorted(nis)

    def with_gate(sys_):
        from fusion.api import GateDecision, Gate

        class Chi2(Gate):
            name = "test_chi2"

            def check(self, nis, dim, state):
                return GateDecision(nis < 9.0 * dim, 1.0), state
        for s in sys_.sensors.values():
            s.gate = Chi2()
        return sys_

    ordered = Loop(with_gate(system()))
    ref_out, ref_nis = run(ordered, msgs)
    # the fast ranges arrive 0.25 s after their stamps (the slow ones in time)
    arrival = sorted(msgs, key=lambda m: m.t + (0.25 if m.sensor == "fast" and m.t > 1.0 else 0.0))
    sched = Loop(with_gate(system(late_policy="replay")))
    out, nis = run(sched, arrival)
    fast, ref_fast = sched.sensors["fast"].counters, ordered.sensors["fast"].counters
    assert ref_fast["rejected"] > 10 and fast["late"] == 0
    assert {k: fast[k] for k in ("received", "used", "rejected")} == {k: ref_fast[k] for k in ("received", "used", "rejected")}
    for c in (s.counters for s in sched.sensors.values()):
        assert c["received"] == c["used"] + c["rejected"] + c["malformed"] + c["late"] + c["absorbed"]
    assert [(s, ok) for s, _, ok in nis] == [(s, ok) for s, _, ok in ref_nis]
    rejected = lambda evs: sorted(round(e.t, 9) for e in evs if isinstance(e, Event) and e.kind == "rejected")
    assert rejected(out) == rejected(ref_out)
    np.testing.assert_allclose(sched.belief.x, ref_out[-1].belief.x, atol=1e-9)
