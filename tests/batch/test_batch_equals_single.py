"""The batched filters give the numbers of N single filters (plugins/filters/) to 1e-12: means,
covariances, innovations, NIS, gate verdicts and counters, on the 4-state UWB model (pv + range, as
shipped in configs/uwb_pv_ukf.yaml) and on the 16-state INS with a non-linear 3-range measurement."""
from __future__ import annotations

import numpy as np
import pytest

from fusion import testing
from fusion.batch import BatchBelief, make_batch_filter

from .conftest import bound_range

FILTERS = ["kf", "ekf", "ukf", "srukf"]
TOL = dict(rtol=1e-12, atol=1e-12)


def assert_same(bb: BatchBelief, singles, tol=TOL):
    for i, b in enumerate(singles):
        np.testing.assert_allclose(bb.x[i], b.x, **tol)
        np.testing.assert_allclose(bb.cov[i], b.cov, **tol)


@pytest.mark.parametrize("name", FILTERS)
def test_uwb_batch_equals_single_filters(uwb, name):
    """20 filters, 200 predict/update cycles over ranges to the 4 beacons in turn, each filter with its own
    initial mean and noisy ranges; a few ranges are gross outliers, so the gate rejects some filters' ranges
    and not others'."""
    rng = np.random.default_rng(7)
    N = 20
    process, gate = uwb.process, uwb.sensors["uwb"].gate
    R = uwb.sensors["uwb"].R
    single = testing.build("filter", name)
    batch = make_batch_filter(testing.build("filter", name))
    truth = np.array([5.0, 4.0, 1.0, 0.5])
    x0 = truth + rng.normal(0, 1.0, (N, 4))
    P0 = np.diag([1.0, 1.0, 0.25, 0.25])
    bb = batch.initial_belief(0.0, x0, P0)
    bs = [single.initial_belief(0.0, x0[i], P0) for i in range(N)]
    beacons = list(uwb.beacons)
    rejected = np.zeros(N, int)
    for k in range(200):
        truth = process.f(truth, None, 0.05)
        model = bound_range(uwb, beacons[k % 4])
        z = model.h(truth) + rng.normal(0, 0.1, (N, 1))
        z[(rng.random(N) < 0.03) & (np.arange(N) < N // 2)] += 5.0   # outliers in half the filters: rejections
        bb = batch.predict(bb, process, None, 0.05)
        bs = [single.predict(b, process, None, 0.05) for b in bs]
        up = batch.update(bb, model, z, R, gate)
        ups = [single.update(b, model, z[i], R, gate) for i, b in enumerate(bs)]
        np.testing.assert_array_equal(up.accepted, [u.accepted for u in ups])
        np.testing.assert_allclose(up.nis, [u.nis for u in ups], rtol=1e-11, atol=1e-12)
        np.testing.assert_allclose(up.innovation, np.array([u.innovation for u in ups]).reshape(N, -1), **TOL)
        rejected += ~up.accepted
        bb, bs = up.belief, [u.belief for u in ups]
        assert_same(bb, bs)
    assert rejected.sum() > 0 and (rejected == 0).any(), "the test needs filters with and without rejections"
    np.testing.assert_array_equal(batch.counters["rejected"], rejected)
    assert batch.counters["updates"].sum() == 200 * N - rejected.sum()


@pytest.mark.parametrize("block", [None, 100 * 16])
@pytest.mark.parametrize("name", ["ekf", "ukf", "srukf"])
def test_ins_batch_equals_single_filters(ranges3d, name, block, monkeypatch):
    """16-state INS (trapezoidal, renormalised quaternion), 8 filters with their own IMU samples and
    initial errors; 10 predictions at 100 Hz then a 3-range update, 30 cycles; also with the process
    model evaluated in blocks of 100 sigma points (CF_BLOCK: blocks that cut filters apart)."""
    if block is not None:
        import fusion.batch.models as bmm
        monkeypatch.setattr(bmm, "CF_BLOCK", block)
    rng = np.random.default_rng(11)
    N = 8
    proc = testing.build("process", "ins", {"integration": "trapezoidal"})
    single = testing.build("filter", name, {"batch_inputs": False} if name != "ekf" else None)
    batch = make_batch_filter(testing.build("filter", name, {"batch_inputs": False} if name != "ekf" else None))
    x0 = np.zeros((N, 16))
    x0[:, 0:3] = rng.normal(0, 1.0, (N, 3))
    x0[:, 3:6] = rng.normal(0, 0.2, (N, 3))
    q = np.array([1.0, 0.0, 0.0, 0.0]) + rng.normal(0, 0.05, (N, 4))
    x0[:, 6:10] = q / np.linalg.norm(q, axis=1, keepdims=True)
    P0 = np.diag([1.0] * 3 + [0.04] * 3 + [1e-3] * 4 + [1e-4] * 3 + [1e-6] * 3)
    bb = batch.initial_belief(0.0, x0, P0)
    bs = [single.initial_belief(0.0, x0[i], P0) for i in range(N)]
    R = np.eye(3) * 0.05 ** 2
    for k in range(30):
        for j in range(10):
            u = np.concatenate([rng.normal([0, 0, -9.81], 0.3, (N, 3)), rng.normal(0, 0.05, (N, 3))], axis=1)
            bb = batch.predict(bb, proc, u, 0.01)
            bs = [single.predict(b, proc, u[i], 0.01) for i, b in enumerate(bs)]
        z = ranges3d.h(x0[:, :]) + rng.normal(0, 0.05, (N, 3))
        up = batch.update(bb, ranges3d, z, R, None)
        ups = [single.update(b, ranges3d, z[i], R, None) for i, b in enumerate(bs)]
        np.testing.assert_allclose(up.nis, [u.nis for u in ups], rtol=1e-10, atol=1e-12)
        bb, bs = up.belief, [u.belief for u in ups]
        assert_same(bb, bs, dict(rtol=1e-12, atol=1e-12))


@pytest.mark.parametrize("name", ["ekf", "ukf"])
def test_repair_is_per_filter(uwb, name):
    """A non-positive-definite covariance in one filter is repaired in that filter only (counted there),
    the same numbers as the single filter's repair; the others are untouched."""
    process = uwb.process
    model = bound_range(uwb, "B2")
    single = testing.build("filter", name)
    batch = make_batch_filter(testing.build("filter", name))
    N = 5
    x = np.tile([5.0, 4.0, 1.0, 0.5], (N, 1))
    P = np.tile(np.diag([1.0, 1.0, 0.25, 0.25]), (N, 1, 1))
    P[2] = np.diag([1.0, -0.5, 0.25, 0.25])                     # not positive definite
    batch.reset(N)
    bb = BatchBelief(0.0, x, P=P)
    z = np.full((N, 1), 25.0)
    R = uwb.sensors["uwb"].R
    if name == "ukf":
        up = batch.update(bb, model, z, R, None)
        ups = [single.update(BatchBelief(0.0, x, P=P).belief(i), model, z[i], R, None) for i in range(N)]
        assert_same(up.belief, [u.belief for u in ups])
    else:
        P[2] = np.diag([1.0, 1.0, 0.25, 0.25])
        P[2, 0, 0] = -30.0                                      # makes S = H P H^T + R negative
        up = batch.update(BatchBelief(0.0, x, P=P), model, z, R, None)
        ups = [single.update(BatchBelief(0.0, x, P=P).belief(i), model, z[i], R, None) for i in range(N)]
        np.testing.assert_allclose(up.nis, [u.nis for u in ups], **TOL)
        assert_same(up.belief, [u.belief for u in ups])
    np.testing.assert_array_equal(batch.counters["not_positive_definite"], [0, 0, 1, 0, 0])
    repairs = [sum(e.kind == "not_positive_definite" for e in u.events) for u in ups]   # single filters
    assert repairs == [0, 0, 1, 0, 0]                                                  # report, not count
