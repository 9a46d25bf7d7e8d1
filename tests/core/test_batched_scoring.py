"""Estimates scored against truth in batches (``TruthComparison.SCORE_BATCH``, ``ErrorTracker.locate`` then
``ErrorTracker.score``): the same statistics, errors and truth rows, to the last bit, as one at a time; and
the truth window's batched rows equal its row at each time (fusion.truth.interpolate_row)."""
import math

import numpy as np
import pytest

from fusion import quaternion as quat
from fusion.api import Belief, Estimate, Message, StateLayout
from fusion.metrics import ErrorTracker, Truth
from fusion.truth import interpolate_row
from fusion.truth_stream import TruthComparison, TruthWindow, _Rows
from fusion.testing.faults import thin_truth

NAMES = ["px", "py", "pz", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "psi", "bax"]
LAYOUT = "p:3 v:3 q:4 psi:1:angle ba:1"


def _stream(seed: int, n_truth: int = 900, n_est: int = 400):
    """Interleaved truth messages (text values, as fusion run reads them: 50 Hz with a gap and a wrapping
    angle) and estimates (random times, some before settling, one non-finite, a NaN covariance), in
    arrival order as the pipeline gives them."""
    rng = np.random.default_rng(seed)
    tt = np.arange(n_truth) * 0.02
    tt = np.concatenate([tt[:300], tt[330:] + 0.0])            # a 0.6 s gap: estimates inside it are not compared
    q = quat.normalize(rng.normal(size=(tt.size, 4)) * 0.05 + [1.0, 0.0, 0.0, 0.0])
    q[::7] *= -1.0                                             # hemisphere flips along the stream
    psi = np.unwrap(np.linspace(0, 9.0, tt.size)) % (2 * math.pi) - math.pi
    vals = np.column_stack([rng.normal(size=(tt.size, 6)).cumsum(0), q, psi, rng.normal(size=tt.size) * 0.01])
    truth = [Message(float(t), "truth", ",".join(f"{v:.9f}" for v in row), i) for i, (t, row) in enumerate(zip(tt, vals))]
    te = np.sort(rng.uniform(-0.05, tt[-1] + 0.05, n_est))
    ests = []
    lay = StateLayout.parse(LAYOUT)
    for k, t in enumerate(te):
        x = rng.normal(size=lay.n)
        x[6:10] = quat.normalize(x[6:10] * 0.05 + [1.0, 0.0, 0.0, 0.0]) * (1.0 + 1e-3 * rng.normal())
        A = rng.normal(size=(lay.n, lay.n)) * 0.1
        P = A @ A.T + np.eye(lay.n) * 0.01
        if k == 200:
            x[0] = math.nan                                    # a diverged estimate: counted non-finite
        if k == 250:
            P[3, 3] = math.nan                                 # NEES skipped
        ests.append(Estimate(float(t), Belief(float(t), x, P=P), "update" if k % 3 else "output", "s"))
    items = [(m.t, 0, m) for m in truth] + [(e.t, 1, e) for e in ests]
    items.sort(key=lambda it: (it[0], it[1]))
    return lay, items


def _run(batch: int, seed: int, **kw):
    lay, items = _stream(seed)
    results = []
    tracker = ErrorTracker(lay, None, settle_s=0.3, **kw)
    comp = TruthComparison(tracker, NAMES, on_result=lambda e, err, row: results.append((e.t, err, row)))
    comp.SCORE_BATCH = batch
    tracker.start(items[0][0])
    for _, kind, obj in items:
        if kind:
            comp.add_estimate(obj)
        else:
            comp.add_truth(obj)
    comp.finish()
    return tracker, results


def _bits(value):
    if isinstance(value, float):
        return np.float64(value).tobytes()
    if isinstance(value, dict):
        return {k: _bits(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return value.tobytes()
    return value


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("batch", [2, 7, 64, 1000])
def test_batches_give_the_one_at_a_time_numbers_bit_for_bit(batch, seed):
    one, res1 = _run(1, seed)
    many, resk = _run(batch, seed)
    s1, sk = one.summary(), many.summary()
    assert repr(s1) == repr(sk)
    assert one._ess.tobytes() == many._ess.tobytes() and one._emax.tobytes() == many._emax.tobytes()
    assert len(res1) == len(resk)
    for (t1, e1, r1), (tk, ek, rk) in zip(res1, resk):
        assert t1 == tk and _bits(e1) == _bits(ek) and _bits(r1) == _bits(rk)
    assert s1["errors"]["samples"] > 100 and one.nonfinite == 1 and s1["consistency"]["nees_skipped"] >= 1
    assert sum(e is None for _, e, _ in res1) > 0            # in the gap, before truth: on_result(est, None, None)


def test_without_attitude_nees_too():
    one, _ = _run(1, 3, nees_attitude=False)
    many, _ = _run(64, 3, nees_attitude=False)
    assert repr(one.summary()) == repr(many.summary()) and one.nees_dof == 8


def test_window_rows_equal_interpolate_row_at_each_time():
    """locate + rows (the batched path) against interpolate_row over the stored samples, times in and around
    the span, in the gap, exactly on samples."""
    _, items = _stream(5)
    w = TruthWindow(NAMES).with_angles(["psi"])
    for _, kind, obj in items:
        if not kind:
            w.add(obj)
    ts = np.concatenate([np.linspace(-0.05, w._t[-1] + 0.05, 997), w._t[::37]])
    located = [w.locate(float(t)) for t in ts]
    rows = w.rows([loc for loc in located if loc is not None])
    k = 0
    for t, loc in zip(ts.tolist(), located):
        ref = interpolate_row(w._t, _Rows(w._v, w.quaternions), t, w.period, w.GAP_PERIODS, w.quaternions,
                              w._angle_cols)
        assert (loc is None) == (ref is None)
        if ref is not None:
            assert rows[k].tobytes() == ref.tobytes()
            k += 1
    assert k > 900


def test_add_with_a_whole_recording_truth_is_the_streamed_scoring():
    """ErrorTracker.add over fusion.metrics.Truth (rows computed at once, no locate) gives the errors and
    truth rows of the streamed, batched comparison (a regular truth rate: the same sample period)."""
    lay, items = _stream(7)
    _, streamed = _run(64, 7)
    truth_msgs = [m for _, kind, m in items if not kind]
    full = Truth.from_messages([m._replace(values=tuple(map(float, m.values.split(",")))) for m in truth_msgs],
                               NAMES, angles=["psi"])
    tr = ErrorTracker(lay, full, settle_s=0.3)
    tr.start(items[0][0])
    errs = [tr.add(e) for _, kind, e in items if kind]
    assert [e is None for e in errs] == [e is None for _, e, _ in streamed]
    assert sum(e is not None for e in errs) > 300
    for mine, (_, theirs, _) in zip(errs, streamed):
        if mine is not None:
            assert _bits(mine) == _bits(theirs)


def test_the_end_of_run_warning_counts_every_estimate_evaluated(tmp_path, monkeypatch):
    """The coarse-truth warning (fusion.pipeline.truth_warnings, before the comparison's finish) counts the
    estimates compared so far: the same text whether they were scored one at a time or waited in a batch."""
    from pathlib import Path

    from fusion import pipeline
    from fusion.config import load_system

    root = Path(__file__).resolve().parents[2]
    out = thin_truth(root / "recordings" / "uwb_route1.log", 0.999)   # truth at 1 Hz
    coarse = tmp_path / "coarse.log"
    coarse.write_text("\n".join(out) + "\n")

    def warning(batch):
        monkeypatch.setattr(TruthComparison, "SCORE_BATCH", batch)
        events = []
        system = load_system(root / "configs" / "uwb_pv_ukf.yaml")
        result = pipeline.run(system, str(coarse), on_event=events.append)
        return [e.detail for e in events if "sparser" in e.detail], result.summary["errors"]

    one, errors_one = warning(1)
    many, errors_many = warning(64)
    assert len(one) == 1 and one == many and repr(errors_one) == repr(errors_many)
