"""Gates are immutable: their decisions are values, counted by the run (fusion.api.GateRun), and a gate's
memory (the reopening gate's integrator) is a per-run state value. So a wired System with a reopening
gate runs twice with identical results, and no gate object changes in a run."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fusion import pipeline, testing
from fusion.api import GateDecision, GateRun, KeepsGateState, has
from fusion.config import load_system

ROOT = Path(__file__).resolve().parents[2]
IEKF = ROOT / "configs" / "ultrasonic_3d_iekf.yaml"
TIMINGS = {"wall_s", "us_per_predict", "us_per_update"}


def test_a_system_with_a_reopening_gate_runs_twice_with_identical_results():
    system = load_system(IEKF)
    gate = system.sensors["us"].gate
    assert gate.name == "reopening" and has(gate, KeepsGateState)
    first, second = (pipeline.run(system, system.recording, [pipeline.Collect()]) for _ in range(2))
    assert ({k: v for k, v in first.summary.items() if k not in TIMINGS}
            == {k: v for k, v in second.summary.items() if k not in TIMINGS})
    np.testing.assert_array_equal(first.last.belief.x, second.last.belief.x)
    np.testing.assert_array_equal(first.last.belief.cov, second.last.belief.cov)
    counts = first.stats.gate_counters["us"]
    assert counts == second.stats.gate_counters["us"]
    # every update the gate refused is a rejected update of the sensor (the run's counters agree)
    assert counts["checked"] > 1000 and 0 < counts["rejected"] <= first.summary["sensors"]["us"]["rejected"]


def test_a_run_changes_no_gate_object():
    """Neither the wired gate nor the run's own copy gains attributes (counters, state) in a run."""
    system = load_system(IEKF)
    run = pipeline.Run(system)
    from fusion.logformat import iter_messages
    from fusion.sources.recording import open_lines

    run.consume(iter_messages(open_lines(system.recording), run.parsed))
    run.finish()
    for gate in (system.sensors["us"].gate, run.scheduler.sensors["us"].gate):
        assert set(vars(gate)) == {"params", "context"}
    assert run.scheduler.gates["us"].counters["checked"] > 0


def test_a_gate_with_memory_refuses_to_decide_without_its_state():
    gate = testing.build("gate", "reopening", {"n_sigma": 2.0})
    with pytest.raises(TypeError, match="GateRun"):
        gate.accept(1.0, 1)
    decision, state = gate.check(1.0, 1, gate.initial_state())
    assert decision == GateDecision(True, 4.0) and state == (False, 40.0)       # a value: full integrator
    assert gate.check(1.0, 1, state) == (decision, state)                      # the same input, the same answer


@pytest.mark.parametrize("name,params", [("chi2", {"probability": 0.99}), ("reopening", {"window": 4})])
def test_two_runs_of_one_gate_do_not_share_memory(name, params):
    gate = testing.build("gate", name, params)
    nis = [0.5, 50.0, 60.0, 70.0, 80.0, 0.1, 90.0, 0.2]
    a, b = GateRun(gate), GateRun(gate)
    first = [a.accept(v, 1) for v in nis]
    assert [b.accept(v, 1) for v in nis] == first
    assert a.counters == b.counters and a.state == b.state


def test_the_docs_gate_example_runs_as_written():
    """docs/writing-plugins.md's gate with memory (the block defining PatientGate), run through a GateRun."""
    import re

    text = (ROOT / "docs" / "writing-plugins.md").read_text()
    block = next(b for b in re.findall(r"```python\n(.*?)```", text, re.S) if "class PatientGate" in b)
    ns: dict = {}
    exec(compile(block, "writing-plugins.md", "exec"), ns)
    gate = ns["PatientGate"](ns["PatientGate"].Params(limit=9.0, patience=3))
    assert has(gate, KeepsGateState)
    run = GateRun(gate)
    assert [run.accept(v, 1) for v in (1.0, 20.0, 20.0, 20.0, 20.0, float("nan"))] == [True, False, False, True,
                                                                                        False, False]
    assert run.counters == {"checked": 6, "rejected": 4, "let_through": 1}
    assert set(vars(gate)) == {"params", "context"}


def test_replay_rewinds_a_gate_state_with_the_belief():
    """late_policy: replay re-runs the messages after a late one from a snapshot; the gates' states are in
    the snapshot, so a gate with memory (here: one that accepts every other measurement) decides as in
    time order, and the final belief is the time-ordered one."""
    import sys

    from fusion.api import Gate

    sys.path.insert(0, str(ROOT / "tests" / "core"))
    from test_scheduler import estimates, stream, system

    from fusion.run import Loop

    class EveryOther(Gate):
        """Accepts every other measurement (memory: the parity, a bool)."""

        name = "every_other"

        def initial_state(self) -> bool:
            return True

        def check(self, nis, dim, state):
            return GateDecision(bool(state), 1.0), not state

    def with_gate(sys_):
        sys_.sensors["fast"].gate = EveryOther()
        return sys_

    msgs = stream(duration=10.0)
    ordered = Loop(with_gate(system()))
    ref = estimates(ordered, msgs)
    held = {5, 17, 40}
    arrival = [m for i, m in enumerate(msgs) if i not in held]
    for i in sorted(held):
        arrival.insert(next(j for j, m in enumerate(arrival) if m.t > msgs[i].t + 1.0), msgs[i])
    sched = Loop(with_gate(system(late_policy="replay")))
    out = list(sched.run(arrival))
    assert [e.kind for e in out if getattr(e, "kind", None) in ("late", "replayed")] == ["replayed"] * 3
    np.testing.assert_allclose(sched.belief.x, ref[-1].belief.x, atol=1e-10)
    np.testing.assert_allclose(sched.belief.cov, ref[-1].belief.cov, atol=1e-10)
    assert sched.gates["fast"].state == ordered.gates["fast"].state
    # the counts are the time-ordered decisions (the re-run ones, the late messages' own included)
    assert dict(sched.gates["fast"].counters) == dict(ordered.gates["fast"].counters)
