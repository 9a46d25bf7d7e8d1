"""The same rows wherever a trial runs: the batched engine, one by one through fusion.pipeline.run, a
local process pool and a 2-worker Dask LocalCluster."""
from __future__ import annotations

import math

import pytest

from fusion.sweep import engines
from fusion.sweep.trial import METRICS, run_trial

COMPARED = [m for m in METRICS if m != "wall_s"] + ["nis_mean_uwb", "status"]


def rows_by_key(pairs):
    return {t.key(): row for t, row in pairs}


def assert_rows_equal(a: dict, b: dict, rel: float = 0.0):
    for k in COMPARED:
        va, vb = a[k], b[k]
        if isinstance(vb, float):
            if math.isnan(vb):
                assert math.isnan(va), k
            else:
                assert va == pytest.approx(vb, rel=rel, abs=rel), k
        else:
            assert va == vb, k


def test_batch_rows_equal_pipeline_rows(trials):
    """The batched engine's rows are the pipeline's (same RunStats code, filters equal to 1e-12): all the
    metrics, counters included; and it really ran batched."""
    ts = trials(seeds=range(4), filters=("ukf", "ekf", "srukf"))
    ready, rest, why = engines.batch_ready(ts)
    assert not rest and not why and len(ready) == 3
    batch = rows_by_key(engines.run_batched(ready))
    assert {r["engine"] for r in batch.values()} == {"batch"}
    for t in ts:
        ref = run_trial(t)
        assert ref["engine"] == "pipeline"
        assert_rows_equal(batch[t.key()], ref, rel=1e-9)


def test_pool_and_dask_rows_equal_serial_rows(trials):
    """A process pool and a 2-worker LocalCluster give the serial rows exactly (a trial is a pure function);
    the batched chunks spread over 2 processes give them to 1e-9."""
    ts = trials(seeds=range(2), filters=("ukf", "ekf"))
    serial = rows_by_key(engines.run_serial(ts))
    pool = rows_by_key(engines.run_pool(ts, 2))
    client = engines.dask_client("local", 2)
    try:
        assert len(client.scheduler_info()["workers"]) == 2
        dask = rows_by_key(engines.run_dask(ts, client))
    finally:
        cluster = client.cluster
        client.close()
        cluster.close()
    ready, _, _ = engines.batch_ready(ts)
    batch2 = rows_by_key(engines.run_batched(ready, jobs=2))          # batched chunks over 2 processes
    assert set(serial) == set(pool) == set(dask) == set(batch2) == {t.key() for t in ts}
    assert {r["engine"] for r in batch2.values()} == {"batch"}
    for k, row in serial.items():
        assert_rows_equal(pool[k], row)
        assert_rows_equal(dask[k], row)
        assert_rows_equal(batch2[k], row, rel=1e-9)


def test_unbatchable_variants_are_named(trials):
    """A variant the batch cannot run (the smoother; the iekf) goes to the pipeline, with the reason."""
    ts = trials(seeds=range(1), filters=("iekf",)) + trials(seeds=range(1), filters=("ukf",), smooth=True)
    ready, rest, why = engines.batch_ready(ts)
    assert not ready and len(rest) == 2
    assert sorted(why.values()) == ["filter 'iekf' has no batched version", "the smoother runs through the pipeline"]


def test_not_lockstep_falls_back_on_the_pipeline(trials, monkeypatch):
    """Seeds whose recordings differ in timing are run one by one through the pipeline, same rows."""
    from fusion.simulate import engine
    from fusion.sweep import batched

    ts = trials(seeds=range(2), filters=("ukf",))
    real = engine.simulate_parts

    def shifted(sc, seed=None, *args, **kw):
        parts = real(sc, seed, *args, **kw)
        if seed == 1:   # drop one range: the two recordings are no longer in lockstep
            st = next(s for s in parts.streams if s.name == "uwb")
            st.t, st.values = st.t[1:], st.values[1:]
        return parts

    monkeypatch.setattr(engine, "simulate_parts", shifted)
    with pytest.raises(batched.NotLockstep):
        batched.run_batch(ts)
    rows = rows_by_key(engines.run_batched([ts]))
    assert {r["engine"] for r in rows.values()} == {"pipeline"}
    for t in ts:
        assert_rows_equal(rows[t.key()], run_trial(t))


def test_a_gate_with_per_run_memory_goes_to_the_pipeline(trials):
    """The batch gates by threshold masks: a reopening gate (state kept per run) would decide otherwise, so
    its variants are routed to the pipeline, with the reason."""
    ts = trials(seeds=range(2), filters=("ukf",), params=[("sensors.uwb.gate", ["{type: reopening, n_sigma: 3.0}"])])
    ready, rest, why = engines.batch_ready(ts)
    assert not ready and len(rest) == 2
    assert set(why.values()) == {"sensor 'uwb': gate 'reopening' keeps per-run state"}
