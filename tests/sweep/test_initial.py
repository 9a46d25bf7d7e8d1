"""``initial: drawn``: the initial mean drawn per seed from N(true start, P0), as a Monte-Carlo NEES test
needs; the same draw for every filter and wherever the trial runs."""
from __future__ import annotations

import numpy as np
import pytest

from fusion.api import ConfigError
from fusion.logformat import iter_messages
from fusion.sweep import engines
from fusion.sweep.trial import INITIAL_STREAM, drawn_mean, recording_of, run_trial, system_of

from .test_engines import assert_rows_equal, rows_by_key


def _first_truth(lines):
    return next(m for m in iter_messages(lines) if getattr(m, "sensor", None) == "truth")


def test_drawn_mean_is_truth_plus_a_draw_of_p0(trials):
    t = trials(seeds=[5], filters=("ukf",), initial="drawn")[0]
    system = system_of(t)
    lines = recording_of(t)
    x0 = drawn_mean(system, lines, t.seed)
    truth = _first_truth(lines)
    names = [ln.split()[3:] for ln in lines if ln.startswith("# fields truth")][0]
    lay = system.layout
    idx = [lay.element_index(n) for n in lay.names]
    want_truth = np.array([float(truth.values[names.index(n)]) for n in lay.names])
    z = np.random.default_rng([5, INITIAL_STREAM]).standard_normal(len(idx))
    np.testing.assert_allclose(x0[idx], want_truth + np.linalg.cholesky(system.P0) @ z, rtol=0, atol=1e-12)
    assert not np.allclose(x0, system.x0)             # it moved off the config's mean


def test_drawn_initial_errors_have_the_covariance_p0(trials):
    """Over 400 seeds the initial error x0 - truth has mean 0 and covariance P0 (chi-square of the mean
    and a 20% band on each variance: far wider than sampling noise at n = 400, far narrower than a
    missing or doubled sd)."""
    t = trials(seeds=[0], filters=("ukf",), initial="drawn")[0]
    system = system_of(t)
    lines = recording_of(t)
    truth = _first_truth(lines)
    names = [ln.split()[3:] for ln in lines if ln.startswith("# fields truth")][0]
    lay = system.layout
    tv = np.array([float(truth.values[names.index(n)]) for n in lay.names])
    err = np.array([drawn_mean(system, lines, s) - tv for s in range(400)])
    var = np.diag(system.P0)
    assert np.all(np.abs(err.mean(axis=0)) < 4 * np.sqrt(var / 400))
    assert np.all(np.abs(err.var(axis=0) / var - 1) < 0.2)


def test_drawn_trials_differ_by_seed_and_agree_between_filters_and_engines(trials):
    ts = trials(seeds=range(3), filters=("ukf", "ekf"), initial="drawn")
    assert len({t.key() for t in ts}) == 6 and all('"drawn"' in t.key() for t in ts)
    ready, rest, why = engines.batch_ready(ts)
    assert not rest and not why
    batch = rows_by_key(engines.run_batched(ready))
    for t in ts:
        ref = run_trial(t)
        assert ref["status"] == "ok", ref.get("error")
        assert_rows_equal(batch[t.key()], ref, rel=1e-9)
    ukf0 = batch[ts[0].key()]["position_rmse_m"]
    assert batch[ts[1].key()]["position_rmse_m"] != ukf0          # another seed, another draw
    plain = run_trial(trials(seeds=[0], filters=("ukf",))[0])
    assert plain["position_rmse_m"] != ukf0                       # not the config's mean


def test_drawn_without_truth_is_a_config_error(trials):
    t = trials(seeds=[0], filters=("ukf",), initial="drawn")[0]
    system = system_of(t)
    lines = [ln for ln in recording_of(t) if ",truth," not in ln and not ln.startswith("# fields truth")]
    with pytest.raises(ConfigError, match="needs truth"):
        drawn_mean(system, lines, 0)
