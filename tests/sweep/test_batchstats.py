"""The batched engine's vectorised statistics (fusion.sweep.batchstats) equal the pipeline's: on real
runs (against RunStats estimate by estimate, the engine's other path) and on synthetic streams with the
edge cases of the streaming truth comparison, against fusion.metrics.ErrorTracker fed through
fusion.truth_stream.TruthComparison exactly as RunStats feeds it."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from fusion.api import Belief, Estimate, Message, StateLayout
from fusion.metrics import ErrorTracker
from fusion.sweep import batched, batchstats
from fusion.truth_stream import TruthComparison

from .test_engines import COMPARED, assert_rows_equal


@pytest.mark.parametrize("filt", ["ukf", "ekf", "srukf"])
def test_vectorised_rows_equal_runstats_rows(trials, monkeypatch, filt):
    """Five seeds of route 1 (drawn initial means: NEES and errors vary by seed), settle 2 s."""
    ts = trials(seeds=range(5), filters=(filt,), params=[("evaluation.settle_s", ["2.0"])], initial="drawn")
    fast = batched.run_batch(ts)
    monkeypatch.setattr(batchstats, "unsupported", lambda *a: "forced")
    slow = batched.run_batch(ts)
    for a, b in zip(fast, slow):
        assert_rows_equal(a, b, rel=1e-12)
        assert a["estimates"] > 100 and a["nees_mean"] > 0


# --------------------------------------------------------------------------- synthetic streams
def reference(layout, names, settle, stream, sensors):
    """Per trial: the row columns from ErrorTracker + TruthComparison, fed in message order as RunStats
    does (the settle clock started by the first estimate, NIS counted after it)."""
    out = []
    N = next(e[3].shape[0] for e in stream if e[0] == "est")
    for i in range(N):
        tr = ErrorTracker(layout, None, settle_s=settle, keep_nis_series=False)
        comp = None
        started = False
        for e in stream:
            if e[0] == "truth":
                if comp is None:
                    comp = TruthComparison(tr, names)
                comp.add_truth(Message(e[1], "truth", tuple(e[2][i].tolist()), None))
            else:
                _, t, sensor, x, P, nis = e
                if not started:
                    tr.start(t)
                    started = True
                    if comp is None:
                        comp = TruthComparison(tr, names)
                tr.add_nis(sensor, float(nis[i]), 1, t=t)
                comp.add_estimate(Estimate(t, Belief(t, x[i].copy(), P=P[i].copy()), "update", sensor))
        if comp is not None:
            comp.finish()
        s = tr.summary()
        err, con = s["errors"], s["consistency"]
        row = {"position_rmse_m": err.get("position_rmse_m", math.nan), "position_max_m": err.get("position_max_m", math.nan),
               "velocity_rmse_mps": err.get("velocity_rmse_mps", math.nan),
               "nees_mean": con.get("nees_mean", math.nan), "nees_in_95_fraction": con.get("nees_in_95_fraction", math.nan),
               "estimates": err.get("samples", 0)}
        for sn in sensors:
            row[f"nis_mean_{sn}"] = con["nis_mean"].get(sn, math.nan)
        out.append(row)
    return out


def vectorised(layout, names, settle, stream, sensors, block=7):
    system = SimpleNamespace(layout=layout, spec=SimpleNamespace(evaluation=SimpleNamespace(settle_s=settle, position=None)))
    N = next(e[3].shape[0] for e in stream if e[0] == "est")
    tt = np.array([e[1] for e in stream if e[0] == "truth"])
    tv = np.stack([e[2] for e in stream if e[0] == "truth"], axis=1) if tt.size else None
    tidx = np.array([k for k, e in enumerate(stream) if e[0] == "truth"])
    est = [(k, e) for k, e in enumerate(stream) if e[0] == "est"]
    assert batchstats.unsupported(system, names, tt, np.array([e[1] for _, e in est]), np.array([k for k, _ in est]),
                                  tidx) is None
    st = batchstats.BatchStats(system, N, names, tt, tv, tidx, sensors, block=block)
    for k, (_, t, sensor, x, P, nis) in est:
        st.add_estimate(t, k, x, P)
        st.add_nis(sensor, t, nis)
    return st.columns()


def compare(got, want):
    for g, w in zip(got, want):
        for k, vw in w.items():
            vg = g[k]
            if isinstance(vw, float) and math.isnan(vw):
                assert isinstance(vg, float) and math.isnan(vg), k
            elif vw is None:
                assert vg is None, k
            else:
                assert vg == pytest.approx(vw, rel=1e-12, abs=1e-300), k


def make_stream(rng, truth_t, est_t, N=6, n_names=("px", "py", "vx", "vy"), truth_lag=0, angle_col=None):
    """Truth samples at truth_t and estimates at est_t, merged by time (a truth line ``truth_lag``
    messages late); estimates near the truth, with random covariances."""
    m = len(n_names)
    base = rng.normal(0, 3, (N, len(truth_t), m)).cumsum(axis=1) * 0.1
    if angle_col is not None:
        base[:, :, angle_col] = (np.linspace(0, 9, len(truth_t))[None] + rng.normal(0, 0.1, (N, len(truth_t))) + np.pi) \
            % (2 * np.pi) - np.pi                       # wrapped heading that turns several times
    items = [(t, 1, ("truth", float(t), base[:, j])) for j, t in enumerate(truth_t)]
    for t in est_t:
        x = rng.normal(0, 1, (N, m)) + (base[:, min(np.searchsorted(truth_t, t), len(truth_t) - 1)] if len(truth_t) else 0)
        A = rng.normal(0, 0.5, (N, m, m))
        P = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(m)
        items.append((t, 0, ("est", float(t), "uwb", x, P, rng.chisquare(1, N))))
    items.sort(key=lambda r: (r[0], r[1]))
    stream = [it[2] for it in items]
    if truth_lag:                                       # truth lines arrive after the estimates they bracket
        tr = [e for e in stream if e[0] == "truth"]
        es = [e for e in stream if e[0] == "est"]
        stream, ti = [], 0
        for k, e in enumerate(es):
            stream.append(e)
            while ti < len(tr) and tr[ti][1] <= e[1] + truth_lag * 0.05:
                stream.append(tr[ti])
                ti += 1
        stream += tr[ti:]
    return stream


LAYOUT = StateLayout.parse("p:2 v:2")
NAMES = ("px", "py", "vx", "vy")


@pytest.mark.parametrize("seed", range(4))
def test_edge_cases_of_the_truth_stream(seed):
    """Estimates before the first truth sample (compared within half the window's period, 0 while it
    holds one sample), after the last (within half the final period), at sample times, inside a gap of
    more than 5 periods (not compared) and at its ends; irregular intervals (the median period moves over
    the first 64 samples and at every 256th); truth that arrives late; settle; small blocks."""
    rng = np.random.default_rng(seed)
    dt = np.where(rng.random(700) < 0.3, 0.1, 0.05) * (1 + 0.01 * rng.standard_normal(700))
    tt = 1.0 + np.cumsum(dt)
    tt = np.concatenate([tt[:300], tt[300:] + 2.0])      # a gap of 2 s (~30 periods)
    est = np.concatenate([[0.2, 0.9, 0.97, 1.0], np.sort(rng.uniform(1.0, tt[-1] + 0.2, 1500)),
                          tt[::37], [tt[299] + 0.01, tt[300] - 0.01, tt[299] + 1.0, tt[-1] + 0.02, tt[-1] + 0.5]])
    est = np.sort(est)
    for lag, settle in ((0, 0.0), (3, 1.5)):
        stream = make_stream(rng, tt, est, truth_lag=lag)
        got = vectorised(LAYOUT, NAMES, settle, stream, ["uwb"])
        want = reference(LAYOUT, NAMES, settle, stream, ["uwb"])
        compare(got, want)
        assert 0 < want[0]["estimates"] < len(est)     # some estimates not compared (gap, edges)


def test_nan_estimates_covariances_and_nis():
    """A NaN mean (left out of the errors, RMSE and max over the others, as ErrorTracker), a
    covariance that is not positive definite and one with a NaN (NEES skipped), NaN NIS (not counted)."""
    rng = np.random.default_rng(5)
    tt = np.arange(0, 20, 0.05)
    stream = make_stream(rng, tt, np.sort(rng.uniform(0, 20, 300)))
    ests = [e for e in stream if e[0] == "est"]
    ests[10][3][0, 1] = np.nan                           # trial 0: a NaN mean
    ests[11][4][1, 2, 2] = -1.0                          # trial 1: not positive definite
    ests[12][4][2, 3, 0] = np.nan                        # trial 2: NaN in the lower triangle
    ests[13][4][3, 0, 3] = np.nan                        # trial 3: NaN only in the upper (never read)
    ests[14][5][4] = np.nan                              # trial 4: a NaN NIS
    got = vectorised(LAYOUT, NAMES, 0.0, stream, ["uwb"])
    want = reference(LAYOUT, NAMES, 0.0, stream, ["uwb"])
    compare(got, want)
    assert math.isfinite(want[0]["position_rmse_m"]) and math.isfinite(want[0]["position_max_m"])
    assert want[0]["estimates"] == want[1]["estimates"] - 1     # the NaN one is not counted


def test_estimates_without_truth_and_truth_without_estimates():
    """No truth at all: NIS only; truth that ends before the estimates start: nothing compared."""
    rng = np.random.default_rng(6)
    stream = [e for e in make_stream(rng, np.arange(0, 5, 0.05), np.sort(rng.uniform(0, 5, 50))) if e[0] == "est"]
    compare(vectorised(LAYOUT, None, 0.0, stream, ["uwb"]), reference(LAYOUT, NAMES, 0.0, stream, ["uwb"]))
    stream = make_stream(rng, np.arange(0, 5, 0.05), np.sort(rng.uniform(10, 15, 50)))
    want = reference(LAYOUT, NAMES, 0.0, stream, ["uwb"])
    compare(vectorised(LAYOUT, NAMES, 0.0, stream, ["uwb"]), want)
    assert want[0]["estimates"] == 0


def test_angle_elements_are_unwrapped_interpolated_and_wrapped():
    """An angle block (heading ``h``, rad): truth unwrapped along the stream, the error wrapped."""
    lay = StateLayout.parse("p:2 h:1:angle")
    names = ("px", "py", "h")
    rng = np.random.default_rng(7)
    stream = make_stream(rng, np.arange(0, 30, 0.05), np.sort(rng.uniform(0, 30, 400)), n_names=names, angle_col=2)
    compare(vectorised(lay, names, 0.0, stream, ["uwb"]), reference(lay, names, 0.0, stream, ["uwb"]))


def test_what_the_vectorised_path_does_not_reproduce_is_named():
    """A quaternion block compared with truth, truth out of order, too many estimates waiting."""
    quat = SimpleNamespace(layout=StateLayout.parse("p:3 q:4"),
                           spec=SimpleNamespace(evaluation=SimpleNamespace(settle_s=0.0, position=None)))
    names = ("px", "py", "pz", "qw", "qx", "qy", "qz")
    one = np.zeros(1, np.int64)
    assert "quaternion" in batchstats.unsupported(quat, names, np.zeros(1), np.zeros(1), one, one)
    plain = SimpleNamespace(layout=LAYOUT, spec=quat.spec)
    assert "order" in batchstats.unsupported(plain, NAMES, np.array([1.0, 0.5]), np.zeros(1), one + 5, np.array([0, 1]))
    n = batchstats.MAX_PENDING + 1                       # every estimate before the one truth sample after them
    assert "wait" in batchstats.unsupported(plain, NAMES, np.array([0.0, 1e6]), np.linspace(1, 2, n),
                                            np.arange(1, n + 1), np.array([0, n + 1]))
    assert batchstats.unsupported(plain, NAMES, np.array([0.0, 1e6]), np.linspace(1, 2, n - 1),
                                  np.arange(1, n), np.array([0, n])) is None


def test_columns_are_the_rows_columns():
    assert set(COMPARED) >= {"position_rmse_m", "nees_mean", "estimates"}
