"""Scheduler: the ReadsBelief capability of a preprocessor and measurements at their own time (issue 11).

A probe preprocessor on the 1-D odometry system of test_scheduler_inputs asks for the belief at a time
before the message it was fed (as ols_trilateration asks at a cycle's mean range time) and emits the fix
stamped there; flush() emits one more fix older than the last input samples (the end of the input).
"""
from __future__ import annotations

from typing import ClassVar

import numpy as np

from fusion.api import Estimate, Message, ReadsBelief, Solver
from fusion.config import SystemSpec, wire
from fusion.registry import make_plugin_manager
from fusion.run import Loop

from test_scheduler_inputs import Batched, Odometry, stream


class Probe(Solver):
    """Passes fixes through, stamped ``lag`` s earlier, after asking for the belief there."""

    name: ClassVar[str] = "probe_test"
    lag = 0.1

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        self.bound = 0
        self.asked: list[tuple[float, float]] = []
        self._last: Message | None = None

    def bind_belief(self, belief_at):
        self.bound += 1
        self._belief_at = belief_at

    def _emit(self, msg: Message) -> list[Message]:
        t = msg.t - self.lag
        b = self._belief_at(t)
        if b is not None:
            self.asked.append((t, b.t))
        return [Message(t, msg.sensor, msg.values, msg.line)]

    def feed(self, message):
        self._last = message
        return self._emit(message)

    def flush(self):
        return self._emit(self._last) if self._last is not None else []


class Plugin:
    from fusion import hookimpl

    @hookimpl
    def fusion_register_components(self, registry):
        registry.add(Odometry)
        registry.add(Probe)


def _system(probe=True):
    _, reg = make_plugin_manager(extra_plugins=[Plugin()])
    fix = {"model": {"type": "position"}, "noise": 0.1}
    if probe:
        fix["preprocessor"] = {"type": "probe_test"}
    spec = SystemSpec.model_validate({
        "name": "odo", "process": "odo_test", "filter": "kf", "beacons": {"A": [0.0, 0.0]},
        "initial": {"mean": {"p": 0.0, "b": 0.0}, "sd": {"p": 1.0, "b": 0.5}},
        "sensors": {"odo": {"role": "input"}, "fix": fix},
    })
    return wire(spec, registry=reg)


def test_belief_at_predicts_to_the_asked_time_and_fixes_are_used_at_their_time():
    """Batched inputs: the belief comes at exactly the time asked and every fix (the flushed one, older than
    the last inputs, too) is used at its own time, none late; the estimates equal those of the same fixes
    given at those times without a preprocessor. Sample by sample the belief may come later."""
    assert isinstance(Probe(), ReadsBelief)
    msgs = sorted(stream() + [Message(9.995, "fix", (8.0,))], key=lambda m: m.t)   # inputs run to 9.99 s
    sys_ = _system()
    sys_.filter = Batched(sys_.filter)
    sched = Loop(sys_)
    probe = sched.sensors["fix"].preprocessor                     # the run's own copy
    assert probe.bound == 1                                       # bound once, when the run loop is wired
    assert sys_.sensors["fix"].preprocessor.bound == 0            # the wired system is not touched
    ups = [e for e in sched.run(msgs) if isinstance(e, Estimate) and e.reason == "update"]
    assert all(abs(tb - t) < 1e-12 for t, tb in probe.asked)
    assert sched.sensors["fix"].counters["late"] == 0
    fix_t = [m.t - Probe.lag for m in msgs if m.sensor == "fix"]
    assert [e.t for e in ups] == fix_t + [9.995 - Probe.lag]      # the last one from flush()
    # reference: the same fixes at those times, no preprocessor
    shifted = [Message(m.t - Probe.lag, m.sensor, m.values) if m.sensor == "fix" else m for m in msgs]
    shifted.append(Message(9.995 - Probe.lag, "fix", (8.0,)))
    ref_sys = _system(probe=False)
    ref_sys.filter = Batched(ref_sys.filter)
    ref = [e for e in Loop(ref_sys).run(sorted(shifted, key=lambda m: m.t))
           if isinstance(e, Estimate) and e.reason == "update"]
    assert [e.t for e in ref] == [e.t for e in ups]
    for a, b in zip(ups, ref):
        np.testing.assert_allclose(a.belief.x, b.belief.x, atol=1e-12)
        np.testing.assert_allclose(a.belief.cov, b.belief.cov, atol=1e-12)
    sys_s = _system()                                             # sample by sample
    sched_s = Loop(sys_s)
    probe_s = sched_s.sensors["fix"].preprocessor
    list(sched_s.run(msgs))
    assert probe_s.asked and all(tb >= t for t, tb in probe_s.asked)


class BadFlush(Probe):
    """A probe whose flush fails in the way ``how`` names (tester6: a preprocessor's flush was not checked)."""

    name: ClassVar[str] = "bad_flush_test"
    how = "raise"

    def flush(self):
        if self.how == "raise":
            raise RuntimeError("boom in flush")
        if self.how == "not_a_list":
            return "fix"
        return [self._last, 3.0]                      # one good message and one that is not


def test_a_failing_flush_is_named_and_the_run_still_ends(monkeypatch):
    """A preprocessor whose flush raises or returns anything but Messages/Fixes: one warning naming it, its held
    messages lost, every estimate before the end the same as a run whose flush emits nothing."""
    msgs = sorted(stream() + [Message(9.995, "fix", (8.0,))], key=lambda m: m.t)

    def run(how):
        class P(BadFlush):
            pass
        P.how = how

        class Plug:
            from fusion import hookimpl

            @hookimpl
            def fusion_register_components(self, registry):
                registry.add(Odometry)
                registry.add(P)
        _, reg = make_plugin_manager(extra_plugins=[Plug()])
        spec = SystemSpec.model_validate({
            "name": "odo", "process": "odo_test", "filter": "kf", "beacons": {"A": [0.0, 0.0]},
            "initial": {"mean": {"p": 0.0, "b": 0.0}, "sd": {"p": 1.0, "b": 0.5}},
            "sensors": {"odo": {"role": "input"}, "fix": {"model": {"type": "position"}, "noise": 0.1,
                                                          "preprocessor": {"type": "bad_flush_test"}}}})
        sched = Loop(wire(spec, registry=reg))
        return sched, list(sched.run(msgs))

    good_sched = Loop(_system())
    good = [e for e in good_sched.run(msgs) if isinstance(e, Estimate) and e.reason == "update"][:-1]  # no flushed fix
    for how, said in (("raise", "flush failed: RuntimeError: boom in flush"),
                      ("not_a_list", "flush returned 'fix'"), ("bad_item", "flush returned")):
        sched, out = run(how)
        warnings = [e for e in out if not isinstance(e, Estimate) and e.kind == "warning" and "flush" in e.detail]
        assert len(warnings) == 1 and said in warnings[0].detail and "bad_flush_test" in warnings[0].detail
        assert "expected a list" in warnings[0].detail or how == "raise"
        ups = [e for e in out if isinstance(e, Estimate) and e.reason == "update"]
        assert [e.t for e in ups] == [e.t for e in good]
        for a, b in zip(ups, good):
            np.testing.assert_array_equal(a.belief.x, b.belief.x)
        assert sched.sensors["fix"].counters["absorbed"] >= 0
