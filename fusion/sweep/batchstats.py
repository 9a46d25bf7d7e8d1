"""The statistics of the batched engine's trials, vectorised over the steps of a run and over the trials:
the row columns that the pipeline's ``RunStats`` (fusion.metrics.ErrorTracker fed through
fusion.truth_stream) computes per estimate, from arrays of estimates (steps, trials, n) and of truth.

It reproduces the streaming rules of ``TruthComparison``/``TruthWindow`` exactly, not just the
whole-recording interpolation: an estimate is evaluated once a truth sample later than it has arrived,
with the truth window's sample period *at that moment* (the median of the last 1024 intervals, updated at
each of the first 64 samples and then every 256th), so the edge cases come out as in ``fusion run``: an
estimate before the first truth sample is compared only within half that period (0 while one sample has
arrived), one after the last within half the final period, one inside a gap of more than 5 periods not
at all. Sums are accumulated in step order (``np.add.accumulate``), as the tracker's running sums, so the
RMSEs, means and fractions equal the pipeline's to rounding (tests/sweep/test_batchstats.py: 1e-12).

:func:`unsupported` names what this path does not reproduce (then the engine feeds ``RunStats`` per
estimate instead): a quaternion block of the state that truth covers (attitude error and 3-dof NEES),
truth out of time order or with samples the window would skip, more than 4096 estimates waiting for truth.

Units: errors in the state's units (m, m/s; angles rad, wrapped to (-pi, pi]); times in s.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from fusion.consistency import chi2_interval

__all__ = ["BatchStats", "unsupported", "MAX_PENDING"]

MAX_PENDING = 4096     # fusion.truth_stream.TruthComparison's default max_pending
_PERIOD_WINDOW = 1024  # TruthWindow.PERIOD_WINDOW
_GAP_PERIODS = 5.0     # TruthWindow.GAP_PERIODS


def _tracker(system: Any, names: Sequence[str] | None):
    """The pipeline's own ErrorTracker set up on a truth window of ``names`` (its element selection:
    which elements, position and velocity groups, angle wrapping, NEES indices)."""
    from fusion.metrics import ErrorTracker
    from fusion.truth_stream import TruthWindow

    ev = system.spec.evaluation
    tr = ErrorTracker(system.layout, None, settle_s=ev.settle_s, position=ev.position, keep_nis_series=False)
    if names:
        tr.set_truth(TruthWindow(names))
    return tr


def unsupported(system: Any, names: Sequence[str] | None, truth_t: np.ndarray | None, step_t: np.ndarray,
                step_idx: np.ndarray, truth_idx: np.ndarray | None) -> str | None:
    """Why :class:`BatchStats` cannot reproduce ``RunStats`` for this run (None when it can). ``step_t``
    and ``step_idx``: time and message index of every estimate; ``truth_t``, ``truth_idx``: of every truth
    message (all of them finite and of the right length: the caller checks)."""
    if not names:
        return None
    tr = _tracker(system, names)
    if tr._quats:
        return "a quaternion block of the state is compared with truth"
    if truth_t.size and np.any(np.diff(truth_t) < 0.0):
        return "truth out of time order"
    if step_t.size:
        rel = _release_index(truth_t, truth_idx, step_t, step_idx)
        waiting = np.arange(step_t.size) - np.searchsorted(rel, step_idx, side="right") + 1
        if waiting.max() > MAX_PENDING:
            return f"more than {MAX_PENDING} estimates wait for truth"
    return None


def _release_index(tt: np.ndarray, tpos: np.ndarray, t: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Message index at which each estimate is evaluated (inf: at the end of the input)."""
    j = np.searchsorted(tt, t, side="right")
    rel = np.full(t.shape, np.inf)
    has = j < tt.size
    rel[has] = np.maximum(idx[has], tpos[j[has]])
    return rel


def _periods(tt: np.ndarray, n: np.ndarray) -> np.ndarray:
    """The truth window's sample period after ``n`` samples (arrays): TruthWindow.add recomputes it at
    each of the first 64 samples and every 256th, as the median of the last 1024 intervals."""
    u = np.where(n <= 64, n, np.maximum(64, (n // 256) * 256))
    d = np.diff(tt)
    out = np.zeros(n.shape)
    for uu in np.unique(u):
        if uu >= 2:
            out[u == uu] = float(np.median(d[max(0, uu - 1 - _PERIOD_WINDOW):uu - 1]))
    return out


def _acc(carry: np.ndarray, vals: np.ndarray) -> np.ndarray:
    """carry + vals[0] + vals[1] + ... in that order (axis 0), as a running ``+=``."""
    if vals.shape[0] == 0:
        return carry
    return np.add.accumulate(np.concatenate([carry[None], vals]), axis=0)[-1]


def _nees(err: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``err^T P^-1 err`` over a stack (k, d), (k, d, d) by Cholesky (LAPACK dpotrf's pivot test) and
    forward substitution; NaN where P is not positive definite or anything is non-finite (as
    fusion.consistency.nees)."""
    from fusion.batch.linalg import cholesky

    k, d = err.shape
    if k == 0:
        return np.zeros(0)
    L, ok = cholesky(P)
    w = np.empty((k, d))
    for i in range(d):
        s = err[:, i] - np.einsum("kj,kj->k", L[:, i, :i], w[:, :i]) if i else err[:, 0].copy()
        w[:, i] = s / np.where(ok, L[:, i, i], 1.0)
    with np.errstate(invalid="ignore", over="ignore"):
        v = np.einsum("kj,kj->k", w, w)
    return np.where(ok & np.isfinite(v), v, np.nan)


class BatchStats:
    """Row statistics of N trials run in lockstep (see the module docstring).

    :param system: the wired System (layout, ``evaluation.settle_s`` and ``position``).
    :param names: truth field names (``# fields truth ...``), or None (no truth: NIS only).
    :param truth_t: (T,) truth times (s, as parsed), non-decreasing; ``truth_v`` (N, T, m) their values;
        ``truth_idx`` (T,) their message indices in the recording.
    :param sensors: the measurement sensors (the ``nis_mean_<sensor>`` columns).
    :param block: steps buffered before they are reduced (memory: block x N x n x n floats).
    """

    def __init__(self, system: Any, N: int, names: Sequence[str] | None, truth_t: np.ndarray | None,
                 truth_v: np.ndarray | None, truth_idx: np.ndarray | None, sensors: Sequence[str],
                 block: int = 512):
        self.N = N
        self.settle_s = float(system.spec.evaluation.settle_s)
        self.t_first: float | None = None
        n = system.layout.n
        self.block = int(block)
        self._t = np.empty(self.block)
        self._idx = np.empty(self.block, np.int64)
        self._x = np.empty((self.block, N, n))
        self._P = np.empty((self.block, N, n, n))
        self._b = 0
        self.nis_count = {s: np.zeros(N, np.int64) for s in sensors}
        self.nis_total = {s: np.zeros(N) for s in sensors}
        self.truth = bool(names) and truth_t is not None and truth_t.size > 0
        tr = _tracker(system, names if self.truth else None)
        self.truth = self.truth and bool(tr._elems)      # truth that names no state element: no errors
        self.compared = np.zeros(N, np.int64)     # estimates in the errors (those with finite errors)
        self.nees_count = np.zeros(N, np.int64)
        self.nees_skipped = np.zeros(N, np.int64)
        self.nees_inside = np.zeros(N, np.int64)
        self.nees_total = np.zeros(N)
        self.acc = {k: (np.zeros(N), np.zeros(N)) for k in ("position", "velocity")}   # (sum sq, max)
        self.pos = self.vel = None
        self.dof = 0
        if not self.truth:
            return
        self.tt = np.asarray(truth_t, float)
        self.tpos = np.asarray(truth_idx, np.int64)
        et = tr._et
        v = np.asarray(truth_v, float)[:, :, et]                      # (N, T, ne): the compared columns
        wrap_cols = np.flatnonzero(tr._wrap)
        if wrap_cols.size:                                            # angles: unwrapped along the stream
            v = v.copy()
            v[:, :, wrap_cols] = np.unwrap(v[:, :, wrap_cols], axis=1)
        self.tv = v
        self.ex, self.wrap = tr._ex, wrap_cols
        self.pos, self.vel = tr._pos, tr._vel
        self.nees_idx, self.nees_pos, self.dof = tr._nees_vec, tr._nees_vec_pos, tr.nees_dof
        self.bounds = chi2_interval(self.dof) if self.dof else (math.nan, math.nan)

    # ------------------------------------------------------------------ feeding
    def step(self, sensor: str, t: float, idx: int, belief: Any, update: Any, m: int) -> None:
        """One batched update of ``sensor`` at ``t`` (message ``idx``): its estimates (the posterior
        ``belief``, a fusion.batch BatchBelief) and NIS (``update.nis``; dimension ``m``)."""
        self.add_estimate(t, idx, belief.x, belief.cov)
        self.add_nis(sensor, t, update.nis)

    def add_nis(self, sensor: str, t: float, nis: np.ndarray) -> None:
        """The NIS (N,) of one update of ``sensor`` at ``t`` (after the step's estimate started the
        settle clock: call :meth:`add_estimate` first)."""
        if t - self.t_first < self.settle_s:
            return
        ok = np.isfinite(nis)
        self.nis_count[sensor] += ok
        self.nis_total[sensor] = self.nis_total[sensor] + np.where(ok, nis, 0.0)

    def add_estimate(self, t: float, idx: int, x: np.ndarray, P: np.ndarray) -> None:
        """The N estimates (x (N, n), P (N, n, n)) of one step at ``t`` (s), message index ``idx``."""
        if self.t_first is None:
            self.t_first = float(t)
        if not self.truth:
            return
        b = self._b
        self._t[b], self._idx[b] = t, idx
        self._x[b] = x
        self._P[b] = P
        self._b = b + 1
        if self._b == self.block:
            self._reduce()

    # ------------------------------------------------------------------ reduction
    def _reduce(self) -> None:
        B, self._b = self._b, 0
        if B == 0:
            return
        t, idx = self._t[:B], self._idx[:B]
        keep = t - self.t_first >= self.settle_s
        if not keep.any():
            return
        t, idx, x, P = t[keep], idx[keep], self._x[:B][keep], self._P[:B][keep]
        tt, tv, T = self.tt, self.tv, self.tt.size
        j = np.searchsorted(tt, t, side="right")
        n = np.where(j == T, T, np.maximum(np.searchsorted(self.tpos, idx), j + 1))
        half = 0.5 * _periods(tt, n)
        i0 = np.clip(j - 1, 0, T - 1)
        i1 = np.clip(j, 0, T - 1)
        t0, t1 = tt[i0], tt[i1]
        dt = t1 - t0
        inner = (j > 0) & (j < T)
        gap = inner & (dt > _GAP_PERIODS * 2.0 * half) & (np.minimum(t - t0, t1 - t) > half)
        has = np.where(j == 0, tt[0] - t <= half, np.where(j == T, t - tt[-1] <= half, ~gap))
        if not has.any():
            return
        t, x, P = t[has], x[has], P[has]
        j, i0, i1, t0, dt, inner = j[has], i0[has], i1[has], t0[has], dt[has], inner[has]
        with np.errstate(invalid="ignore", divide="ignore"):
            f = np.where(inner & (dt > 0), (t - t0) / np.where(dt > 0, dt, 1.0), 1.0)
        v0 = tv[:, np.where(j == 0, 0, i0)]                            # (N, k, ne)
        v1 = tv[:, i1]
        row = np.where(inner[None, :, None], v0 + f[None, :, None] * (v1 - v0), np.where(
            (j == 0)[None, :, None], tv[:, :1], tv[:, -1:]))
        if self.wrap.size:
            row[:, :, self.wrap] = (row[:, :, self.wrap] + math.pi) % (2.0 * math.pi) - math.pi
        xt = np.swapaxes(row, 0, 1)                                    # (k, N, ne)
        e = x[:, :, self.ex] - xt
        if self.wrap.size:
            e[:, :, self.wrap] = (e[:, :, self.wrap] + math.pi) % (2.0 * math.pi) - math.pi
        fin = np.isfinite(e).all(axis=2)                               # (k, N): ErrorTracker leaves the others out
        self.compared += fin.sum(axis=0)
        for key, cols in (("position", self.pos), ("velocity", self.vel)):
            if cols is None:
                continue
            sq = 0.0
            for c in cols:                                             # Python's sum(...): in column order
                sq = sq + e[:, :, c] * e[:, :, c]
            norm = np.sqrt(sq)
            ss, mx = self.acc[key]
            with np.errstate(invalid="ignore"):
                top = np.fmax.reduce(np.where(fin, norm, np.nan), axis=0)
            self.acc[key] = (_acc(ss, np.where(fin, norm * norm, 0.0)), np.fmax(mx, top))
        if self.dof:
            k, N = e.shape[:2]
            ni = self.nees_idx
            Ps = P[:, :, ni[:, None], ni[None, :]].reshape(k * N, ni.size, ni.size)
            val = _nees(-e[:, :, self.nees_pos].reshape(k * N, -1), Ps).reshape(k, N)
            ok = np.isfinite(val)
            lo, hi = self.bounds
            self.nees_skipped += (~ok).sum(axis=0)
            self.nees_count += ok.sum(axis=0)
            self.nees_inside += (ok & (lo <= val) & (val <= hi)).sum(axis=0)
            self.nees_total = _acc(self.nees_total, np.where(ok, val, 0.0))

    # ------------------------------------------------------------------ rows
    def columns(self) -> list[dict[str, Any]]:
        """Per trial: the error, NEES and NIS columns of its row (fusion.sweep.trial.row_of's values)."""
        self._reduce()
        out = []
        nan = math.nan
        for i in range(self.N):
            c = int(self.compared[i])
            r: dict[str, Any] = {}
            for key, col in (("position", "position"), ("velocity", "velocity")):
                cols = self.pos if key == "position" else self.vel
                ss, mx = self.acc[key]
                ok = self.truth and c and cols is not None
                r[f"{col}_rmse"] = math.sqrt(float(ss[i]) / c) if ok else nan
                r[f"{col}_max"] = float(mx[i]) if ok else nan
            row = {"position_rmse_m": r["position_rmse"], "position_max_m": r["position_max"],
                   "velocity_rmse_mps": r["velocity_rmse"], "attitude_rmse_deg": nan}
            cnt, sk = int(self.nees_count[i]), int(self.nees_skipped[i])
            if cnt or sk:
                row["nees_mean"] = float(self.nees_total[i]) / cnt if cnt else None
                row["nees_in_95_fraction"] = int(self.nees_inside[i]) / cnt if cnt else None
            else:
                row["nees_mean"] = row["nees_in_95_fraction"] = nan
            row["estimates"] = c if self.truth else 0
            for s, counts in self.nis_count.items():
                k = int(counts[i])
                row[f"nis_mean_{s}"] = float(self.nis_total[s][i]) / k if k else nan
            out.append(row)
        return out
