"""fusion.run.integrator.Integrator: advance(belief, t) -> (belief, items) predicts through the held input,
emitting the fixed-rate outputs on the way; a run of samples in one predict_inputs call equals the samples one
by one. Checked against the filter's own predictions composed by hand."""
import math
import sys
from pathlib import Path

import numpy as np

from fusion.api import Belief, Estimate, Event
from fusion.run.checks import Failures
from fusion.run.integrator import Integrator
from fusion.run.tally import Tally

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))
from test_scheduler_inputs import Batched, system as odo_system  # noqa: E402


def _integrator(system, batch=False):
    return Integrator(system, system.filter, system.process, Tally(), [], Failures(), batch=batch)


def _belief():
    return Belief(0.0, np.array([0.0, 0.1]), P=np.diag([0.1, 0.01]))


def test_advance_predicts_with_the_held_sample_and_emits_the_outputs_on_the_way():
    system = odo_system(rate_hz=10.0)
    ig = _integrator(system)
    ig.started(0.0)
    ig.u, ig.u_t = np.array([1.1]), 0.0
    start = _belief()
    x0 = start.x.copy()
    belief, items = ig.advance(start, 0.35)
    np.testing.assert_array_equal(start.x, x0)               # the belief given is not changed
    outputs = [i for i in items if isinstance(i, Estimate)]
    assert [round(o.t, 12) for o in outputs] == [0.1, 0.2, 0.3] and all(o.reason == "output" for o in outputs)
    ref = start
    for t in [o.t for o in outputs] + [0.35]:                   # the same steps by hand, at the output ticks
        ref = system.filter.predict(ref, system.process, np.array([1.1]), t - ref.t)
    np.testing.assert_array_equal(belief.x, ref.x)           # the same operations: equal, not close
    np.testing.assert_array_equal(belief.cov, ref.cov)
    assert belief.t == 0.35 and ig.next_output == 0.4 and ig.tally.steps["predict"] == 4


def test_a_gap_longer_than_max_predict_is_bounded_and_told():
    system = odo_system()
    system.spec.scheduler.max_predict_s = 1.0
    ig = _integrator(system)
    ig.started(0.0)
    ig.u, ig.u_t = np.array([1.1]), 0.0
    belief, items = ig.advance(_belief(), 10.0)
    gaps = [i for i in items if isinstance(i, Event) and i.kind == "gap"]
    assert len(gaps) == 1 and belief.t == 10.0
    ref = system.filter.predict(_belief().with_(t=9.0), system.process, np.array([1.1]), 1.0)
    np.testing.assert_array_equal(belief.cov, ref.cov)       # grown over 1 s, not 10


def test_a_run_of_samples_in_one_call_equals_the_samples_one_by_one():
    rng = np.random.default_rng(3)
    samples = [(0.01 * k, np.array([1.0 + 0.01 * rng.normal()])) for k in range(1, 50)]
    outs = []
    for batch in (False, True):
        system = odo_system()
        if batch:
            system.filter = Batched(system.filter)
        ig = _integrator(system, batch=batch)
        ig.started(0.0)
        ig.u, ig.u_t = np.array([1.0]), 0.0
        belief, _ = ig.integrate(_belief(), samples, 0.6, "odo")
        # one by one, the samples go to their own times and the measurement at 0.6 predicts the rest
        belief, _ = ig.advance(belief, 0.6)
        outs.append((belief, ig.u, ig.u_t, system.filter))
    (a, ua, ta, _), (b, ub, tb, batched) = outs
    assert batched.calls == 1 and ig.tally.counters["batched_predicts"] == 1
    assert a.t == b.t == 0.6 and ta == tb and np.array_equal(ua, ub)
    # the same predictions in the same order: equal to rounding of the sums (a few ulps of O(1) values)
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-13)
    np.testing.assert_allclose(a.cov, b.cov, rtol=0, atol=1e-13)


def test_no_input_yet_moves_the_belief_s_time_only():
    system = odo_system()
    ig = _integrator(system)
    ig.started(0.0)
    belief, items = ig.advance(_belief(), 0.5)
    assert belief.t == 0.5 and items == [] and np.array_equal(belief.x, _belief().x)
    assert math.isinf(ig.next_output)
