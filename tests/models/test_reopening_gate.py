"""reopening gate (paper 003 echo rejection, Crazyflie-style re-opening): the integrator's state machine on
scripted NIS sequences, and on purpose-built arrival streams through the IEKF: every echo rejected, and a
wrong, over-confident belief recovered (the gate opens, the filter converges, the gate closes again),
where a plain n-sigma gate locks the truth out for good."""
from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from fusion import testing
from fusion.api import Belief, BuildContext, GateRun, Message

LAB = {"B1": [0, 0, 0], "B2": [2.6, 0, 0], "B3": [0, 2.6, 0], "B4": [0, 0, 2.6]}
C, T, SIGMA = 340.0, 0.225, 2e-4


def _gate(**params):
    """The gate bound to a run of its own (fusion.api.GateRun: its state and counts)."""
    return GateRun(testing.build("gate", "reopening", params))


def test_closed_gate_is_n_sigma():
    g = _gate(n_sigma=2.0)
    assert g.accept(3.99, 1) and not g.accept(4.01, 1)
    assert not g.accept(float("nan"), 1)
    assert g.counters["rejected"] == 2 and g.counters["checked"] == 3
    from scipy.stats import chi2
    assert g.gate.threshold(3) == pytest.approx(chi2.ppf(chi2.cdf(4.0, 1), 3), rel=1e-9)


def test_opens_when_almost_everything_is_rejected_and_closes_once_samples_fit():
    g = _gate(n_sigma=2.0, window=10, open_fraction=0.1, close_fraction=0.9)
    # closed, integrator 10: each misfit takes one off; it opens when the integrator drops below 1
    for k in range(9):
        assert not g.accept(100.0, 1) and not g.state.is_open, k
    assert not g.accept(100.0, 1) and g.state.is_open and g.counters["opened"] == 1   # 10th misfit: integrator 0
    assert g.last.reasons == ("opened",)
    assert g.accept(100.0, 1) and g.accept(1e6, 1)                      # open: everything passes
    assert g.counters["accepted_open"] == 2 and g.last.threshold == float("inf")
    for k in range(9):                                                   # fits: 1, 2, ..., 9 (not > 9)
        assert g.accept(0.5, 1) and g.state.is_open, k
    assert g.accept(0.5, 1) and not g.state.is_open                     # 10 > 9: closed again
    assert g.counters["closed"] == 1
    assert not g.accept(100.0, 1)                                       # and gating again


def test_an_echo_rate_does_not_open_it():
    """Echoes are a minority: with 1 misfit in 4 the integrator climbs; the gate never opens."""
    g = _gate(window=20)
    for k in range(400):
        g.accept(100.0 if k % 4 == 0 else 0.3, 1)
    assert g.counters["opened"] == 0 and g.counters["rejected"] == 100


def test_params_checked():
    with pytest.raises(ValidationError):
        _gate(open_fraction=0.9, close_fraction=0.5)
    with pytest.raises(ValidationError):
        _gate(n_sigma=-1.0)


# --------------------------------------------------------------------------- streams through the IEKF
def _system(gate):
    proc = testing.build("process", "firing_clock", {"position_sd": 0.002, "period_sd": 1e-7})
    ctx = BuildContext(layout=proc.layout, beacons={k: np.array(v, float) for k, v in LAB.items()}, sensor="us")
    model = testing.build("measurement", "arrival_time", {}, ctx)
    return proc, model, testing.build("filter", "iekf", {}), gate


def _stream(r, n, rng, echoes=()):
    """n firings from a robot at r: (t, beacon, arrival); echo indices get 0.3-3 m of extra path."""
    out = []
    names = list(LAB)
    for k in range(n):
        b = names[k % 4]
        a = 0.137 + k * T + np.linalg.norm(r - np.array(LAB[b])) / C + rng.normal(0, SIGMA)
        if k in echoes:
            a += rng.uniform(0.3, 3.0) / C
        out.append((a, b))
    return out


def _run(system, belief, stream):
    proc, model, flt, gate = system
    accepted = []
    for a, b in stream:
        belief = flt.predict(belief, proc, None, a - belief.t) if a > belief.t else belief
        obs = model.observe(Message(a, "us", (b, a, 1.0)))
        res = flt.update(belief.with_(t=a), obs.model, obs.z, np.array([[SIGMA ** 2]]), gate)
        belief = res.belief
        accepted.append(res.accepted)
    return belief, np.array(accepted)


@pytest.mark.parametrize("seed", range(3))
def test_every_echo_rejected(seed):
    rng = np.random.default_rng(seed)
    r = np.array([2.37, 2.2, 1.35])                  # the paper's worst position (row 4 of Tables I/II)
    echoes = set(rng.choice(np.arange(40, 440), 50, replace=False).tolist())
    stream = _stream(r, 440, rng, echoes)
    system = _system(_gate(n_sigma=2.0))
    x0 = np.r_[r + rng.normal(0, 0.05, 3), T, 0.137 - T]
    b0 = Belief(stream[0][0] - T, x0, P=np.diag([0.05 ** 2] * 3 + [1e-8, 1e-4]))
    belief, acc = _run(system, b0, stream)
    assert not acc[sorted(echoes)].any()                                 # all 50 echoes rejected
    genuine = np.array([k for k in range(40, 440) if k not in echoes])
    # genuine arrivals outside 2 sigma: binomial(350, 4.6 %) ~ 16 +- 4; allow a little for the estimate's own error
    assert (~acc[genuine]).sum() < 35
    assert system[3].counters["opened"] == 0
    assert np.abs(belief.x[:3] - r).max() < 0.05


def test_wrong_belief_recovers_only_with_reopening():
    rng = np.random.default_rng(11)
    r = np.array([1.21, 1.15, 1.36])
    stream = _stream(r, 800, rng)
    x0 = np.r_[r + np.array([0.35, -0.3, 0.25]), T, 0.137 - T]       # 0.5 m off ...
    b0 = Belief(stream[0][0] - T, x0, P=np.diag([0.003 ** 2] * 3 + [1e-12, 1e-12]))   # ... and sure of it
    plain = _system(GateRun(testing.build("gate", "chi2", {"n_sigma": 2.0})))
    belief, acc = _run(plain, b0, stream)
    # locked out: the arrivals it still accepts are those the wrong state explains (t absorbs a common delay)
    assert np.linalg.norm(belief.x[:3] - r) > 0.3 and acc.mean() < 0.75
    gate = _gate(n_sigma=2.0, window=40)
    belief, acc = _run(_system(gate), b0, stream)
    assert gate.counters["opened"] >= 1 and not gate.state.is_open         # opened, then closed again
    assert np.linalg.norm(belief.x[:3] - r) < 3 * belief.sd[:3].max()     # within 3 sd of the truth again
    assert acc[-100:].mean() > 0.85                                        # and gating normally at the end
