"""The batched engine's recordings without text (fusion.sweep.lockstep) equal the text path: the
simulated recording rendered, parsed, decoded and observed message by message."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fusion.sweep import lockstep
from fusion.sweep.grid import trials_of
from fusion.sweep.trial import recording_of, system_of

ROOT = Path(__file__).resolve().parents[2]


def test_round_text_is_float_of_the_fixed_decimal_text():
    """round_text(v, d) == float(f"{v:.{d}f}") bit for bit: random values over 30 decades, exact ties
    of binary fractions (0.125 -> 0.12), halves near the product's rounding, signed zeros, huge values."""
    rng = np.random.default_rng(1)
    v = np.concatenate([rng.normal(0, 1, 20000) * 10.0 ** rng.integers(-12, 18, 20000),
                        np.arange(-2000, 2000) / 8.0, np.arange(-500, 500) * 0.0005 + 1e-17,
                        (np.arange(0, 4000) + 0.5) / 1e4, [0.0, -0.0, -1e-9, 1e-9, 2.0 ** 60, -3e22, 1e300]])
    for d in (0, 1, 2, 3, 4, 6, 9, 12):
        got = lockstep.round_text(v, d)
        want = np.array([float(f"{x:.{d}f}") for x in v.tolist()])
        assert np.array_equal(got.view(np.int64), want.view(np.int64)), d   # bits, signs of zero included


CASES = [("configs/uwb_pv_ukf.yaml", "scenarios/uwb_route1.yaml", []),
         ("configs/uwb_pv_ukf_line.yaml", "scenarios/uwb_route2_line.yaml", []),
         ("configs/example_2d.yaml", "scenarios/example_2d.yaml", []),
         ("configs/uwb_pv_ukf.yaml", "scenarios/uwb_route1.yaml",       # outliers, another precision and rate
          [("scenario.sensors.uwb.outlier_prob", ["0.05"]), ("scenario.sensors.uwb.precision", ["2"]),
           ("scenario.truth.rate_hz", ["7"]), ("scenario.duration", ["15"])])]


def assert_same(a: lockstep.Lockstep, b: lockstep.Lockstep) -> None:
    assert len(a.events) == len(b.events)
    for ea, eb in zip(a.events, b.events):
        assert ea[0] == eb[0]
        if ea[0] == "meas":
            assert ea[1:4] == eb[1:4]                     # sensor, time, the same bound model
            assert ea[4].dtype == eb[4].dtype and np.array_equal(ea[4], eb[4])
        else:
            assert ea == eb
    assert a.truth_names == b.truth_names and a.truth_ok == b.truth_ok
    assert np.array_equal(a.truth_t, b.truth_t) and np.array_equal(a.truth_v, b.truth_v)
    assert np.array_equal(a.truth_idx, b.truth_idx) and a.truth_lines == b.truth_lines
    assert [(h.fields, h.meta, h.beacons, h.repeating) for h in a.headers] == \
           [(h.fields, h.meta, h.beacons, h.repeating) for h in b.headers]


@pytest.mark.parametrize("config,scenario,params", CASES)
def test_simulation_equals_the_parsed_text(config, scenario, params):
    ts = trials_of(str(ROOT / config), str(ROOT / scenario), range(3), [None], params)
    system = system_of(ts[0])
    fast = lockstep.from_simulation(system, ts)
    assert fast.source == "simulation"
    assert_same(fast, lockstep.from_texts(system, [recording_of(t) for t in ts]))


def test_what_the_fast_path_does_not_cover_goes_through_the_text(monkeypatch):
    """A column mixing labels and numbers: rendered and parsed (the same arrays as the text path)."""
    from fusion.simulate import engine

    ts = trials_of(str(ROOT / CASES[0][0]), str(ROOT / CASES[0][1]), range(2), [None], [("scenario.duration", ["5"])])
    real = engine.simulate_parts

    def mixed(sc, seed=None, *args, **kw):
        parts = real(sc, seed, *args, **kw)
        st = next(s for s in parts.streams if s.name == "uwb")
        st.values = [(b, r if i % 7 else f"{r:.4f}x") for i, (b, r) in enumerate(st.values)]
        return parts

    monkeypatch.setattr(engine, "simulate_parts", mixed)
    calls = []
    real_texts = lockstep.from_texts
    monkeypatch.setattr(lockstep, "from_texts", lambda *a: calls.append(1) or real_texts(*a))
    system = system_of(ts[0])
    with pytest.raises(lockstep.NotLockstep, match="malformed"):   # '1.2345x' is malformed in the text
        lockstep.from_simulation(system, ts)
    assert calls == [1]


def test_seeds_out_of_lockstep_are_refused():
    """Dropouts are random per seed: the recordings differ in their messages."""
    ts = trials_of(str(ROOT / CASES[0][0]), str(ROOT / CASES[0][1]), range(2), [None],
                   [("scenario.duration", ["10"]), ("scenario.sensors.uwb.dropout_prob", ["0.2"])])
    with pytest.raises(lockstep.NotLockstep):
        lockstep.from_simulation(system_of(ts[0]), ts)
