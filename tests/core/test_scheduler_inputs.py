"""Scheduler with an input sensor: sample-by-sample integration, batching, alignment, gaps, rejections."""
import numpy as np
import pytest

from fusion.api import Block, Estimate, Event, Message, Params, ProcessModel, RejectedMessage, StateLayout
from fusion.config import SystemSpec, wire
from fusion.registry import make_plugin_manager
from fusion.run import Loop


class Odometry(ProcessModel):
    """p' = p + u dt (1-D, u a measured speed in m/s); bias block b added to u. Aligns b from a static start."""

    name = "odo_test"
    input_dim = 1
    linear = True

    class Params(Params):
        q: float = 0.01

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        self.layout = StateLayout([Block("p", 1), Block("b", 1)])

    def f(self, x, u, dt):
        out = np.array(x, float, copy=True)
        out[..., 0] += (u[0] - out[..., 1]) * dt
        return out

    def Q(self, x, u, dt):
        return np.diag([self.params.q * dt, 1e-6 * dt])

    def input_from(self, message):
        u = message.floats()
        if abs(u[0]) > 10:
            raise RejectedMessage(f"speed {u[0]} beyond the 10 m/s range")
        return u

    def align(self, x0, P0, u_mean):
        x0 = x0.copy()
        x0[1] = u_mean[0]  # at rest, the mean reading is the bias
        return x0, P0


class Batched:
    """Adds predict_inputs (a loop of predict) to a filter, to exercise the scheduler's batching."""

    def __init__(self, inner):
        self.inner = inner
        self.name = inner.name
        self.calls = 0

    def __getattr__(self, item):
        if item == "inner":  # while copy.deepcopy rebuilds the object, before __dict__ is filled
            raise AttributeError(item)
        return getattr(self.inner, item)

    def predict_inputs(self, belief, process, us, dts):
        self.calls += 1
        for u, dt in zip(us, dts):
            belief = self.inner.predict(belief, process, u, dt)
        return belief


class Plugin:
    from fusion import hookimpl

    @hookimpl
    def fusion_register_components(self, registry):
        registry.add(Odometry)


def system(align_s=0.0, max_gap=None, rate_hz=None):
    _, reg = make_plugin_manager(extra_plugins=[Plugin()])
    spec = SystemSpec.model_validate({
        "name": "odo", "process": "odo_test", "filter": "kf",
        "beacons": {"A": [0.0, 0.0]},
        "initial": {"mean": {"p": 0.0, "b": 0.0}, "sd": {"p": 1.0, "b": 0.5}, "align_s": align_s},
        "sensors": {"odo": {"role": "input", "max_gap": max_gap},
                    "fix": {"model": {"type": "position"}, "noise": 0.1}},
        "output": {"rate_hz": rate_hz},
    })
    return wire(spec, registry=reg)


def stream(bias=0.3, seed=0, gap=None, bad=()):
    rng = np.random.default_rng(seed)
    msgs = []
    for k in range(1000):  # 100 Hz for 10 s; at rest for 2 s, then 1 m/s
        t = k * 0.01
        if gap and gap[0] <= t < gap[1]:
            continue
        v = 0.0 if t < 2.0 else 1.0
        val = 99.0 if k in bad else v + bias + 0.01 * rng.normal()
        msgs.append(Message(t, "odo", (val,)))
    for k in range(1, 40):  # position fixes at 4 Hz
        t = k * 0.25 + 0.003
        p = 0.0 if t < 2.0 else t - 2.0
        msgs.append(Message(t, "fix", (p + 0.1 * rng.normal(),)))
    return sorted(msgs, key=lambda m: m.t)


def run(sys_, msgs, batched=False):
    if batched:
        sys_.filter = Batched(sys_.filter)
    sched = Loop(sys_)
    out = list(sched.run(msgs))
    return sched, [e for e in out if isinstance(e, Estimate)], [e for e in out if isinstance(e, Event)]


def test_batched_inputs_equal_sample_by_sample():
    msgs = stream()
    _, ref, _ = run(system(), msgs)
    sys_b = system()
    sched, got, _ = run(sys_b, msgs, batched=True)
    assert sched.filter.calls >= 30  # inputs between fixes went in batches (the run's own copy)
    assert sys_b.filter.calls == 0   # the wired system is not modified by a run
    assert len(got) == len(ref)
    for a, b in zip(got, ref):
        assert a.t == b.t
        np.testing.assert_allclose(a.belief.x, b.belief.x, atol=1e-12)
        np.testing.assert_allclose(a.belief.cov, b.belief.cov, atol=1e-12)


def test_alignment_estimates_bias_from_static_start():
    sched, est, _ = run(system(align_s=1.5), stream(bias=0.3))
    # Before alignment no estimate; the first estimate already knows the bias from the mean static reading.
    assert est[0].t > 1.5
    assert est[0].belief.x[1] == pytest.approx(0.3, abs=0.01)
    _, est0, _ = run(system(), stream(bias=0.3))
    assert abs(est0[0].belief.x[1] - 0.3) > 0.2


def test_out_of_range_input_rejected_and_counted():
    sys_ = system()
    sched, est, ev = run(sys_, stream(bad={500, 501, 502}))
    assert sched.sensors["odo"].counters["rejected"] == 3
    assert sum(1 for e in ev if e.kind == "rejected" and e.sensor == "odo") == 3
    assert abs(est[-1].belief.x[0] - (est[-1].t - 2.0)) < 0.3  # integrating 99 m/s would be far off


def test_input_gap_reported_and_run_goes_on():
    sys_ = system(max_gap=0.1)
    sched, est, ev = run(sys_, stream(gap=(5.0, 5.6)))
    gaps = [e for e in ev if e.kind in ("gap", "resumed")]
    # told while the fixes go on (once), then its end with the length
    assert [e.kind for e in gaps] == ["gap", "resumed"] and "while fix goes on" in gaps[0].detail
    assert "after 0.6" in gaps[1].detail
    assert est[-1].t > 9.0


def test_fixed_rate_outputs_with_inputs():
    sys_ = system(rate_hz=10)
    _, est, _ = run(sys_, stream(), batched=True)
    ticks = [e.t for e in est if e.reason == "output"]
    assert len(ticks) >= 95
    np.testing.assert_allclose(np.diff(ticks), 0.1, atol=1e-9)
