"""Errors of a run against the recording's truth: the ``errors`` and ``consistency`` of the summary.

``truth`` lines of a recording carry the true state by block-prefixed names (DESIGN.md, log format):
``# fields truth px py pz vx vy vz qw qx qy qz`` (more, e.g. biases ``bax bay ..``, or a 2-D ``px py vx vy``).

    truth = Truth.from_messages(messages, header.fields["truth"])
    tracker = ErrorTracker(layout, truth, settle_s=0.0)
    for est in estimates:
        tracker.add(est)                                  # errors of this estimate, or None
        if est.update is not None:
            tracker.add_nis(est.sensor, est.update.nis, est.update.innovation.size, t=est.t)
    summary.update(tracker.summary())                     # {"errors": {...}, "consistency": {...}}

What is compared (by element name, so any state layout works):

- position: block ``p`` (or elements ``px py pz`` when there is no block ``p``) vs truth ``px py [pz]``;
  error norm in m. Velocity likewise with ``v`` (m/s).
- attitude: a quaternion block (``q``, Hamilton, scalar first, body-to-NED) vs the truth quaternion of the
  same element names: the angle of ``q_true^-1 (x) q_est`` in degrees (sign of q irrelevant).
- every state element that truth names: ``x_est - x_true`` (angle blocks wrapped to (-pi, pi]).

Errors are evaluated at **every** estimate passed to ``add`` (reason ``update`` and ``output`` alike), once
per call, after the first ``settle_s`` seconds (from the first time seen), where truth exists at that time
(linear interpolation). When a run emits both fixed-rate outputs and per-update estimates, both count, so
the RMSE weights the more frequent kind more; pass ``reasons={"output"}`` to evaluate only one kind.
"""
from __future__ import annotations

import bisect
import math
from typing import Collection, Sequence

import numpy as np

from fusion import quaternion as quat
from fusion.api import Estimate, Message, StateLayout
from fusion.consistency import ChiSquareStat, NisTracker, nees

__all__ = ["Truth", "ErrorTracker", "attitude_error_deg"]


# --------------------------------------------------------------------------- quaternions (scalar first)
def attitude_error_deg(q_true: np.ndarray, q_est: np.ndarray) -> np.ndarray:
    """Rotation angle (deg, in [0, 180]) of ``q_true^-1 (x) q_est`` for quaternions (..., 4), scalar first.
    Neither needs unit norm; ``q`` and ``-q`` give the same angle."""
    d = quat.multiply(quat.conjugate(np.asarray(q_true, float)), np.asarray(q_est, float))
    return np.degrees(2.0 * np.arctan2(np.linalg.norm(d[..., 1:], axis=-1), np.abs(d[..., 0])))


def _qmul_conj(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float, float]:
    """``conj(a) (x) b`` for one pair of quaternions as floats (scalar path, ~1 us instead of ~30 us)."""
    aw, ax, ay, az = a[0], -a[1], -a[2], -a[3]
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


def _slerp(q0: np.ndarray, q1: np.ndarray, f: float) -> list[float]:
    """Spherical interpolation from unit q0 to q1 (shorter arc) at fraction f; unit result (floats: this
    runs once per estimate, where Python floats beat numpy calls on 4-vectors)."""
    a, b = q0.tolist(), q1.tolist()
    dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
    if dot < 0.0:
        b, dot = [-v for v in b], -dot
    if dot > 0.9995:  # nearly equal: normalised lerp (error < 1e-9 rad)
        q = [u + f * (v - u) for u, v in zip(a, b)]
        n = math.sqrt(sum(v * v for v in q))
        return [v / n for v in q]
    th = math.acos(dot)
    s = math.sin(th)
    w0, w1 = math.sin((1.0 - f) * th) / s, math.sin(f * th) / s
    return [w0 * u + w1 * v for u, v in zip(a, b)]


# --------------------------------------------------------------------------- truth
def interpolate_row(tl: Sequence[float], rows, t: float, period: float, gap_periods: float,
                    quaternions: dict[str, list[int]], angle_cols: Sequence[int]) -> np.ndarray | None:
    """The row of ``rows`` (indexable by sample, each (m,)) at time ``t`` between the sorted sample times
    ``tl``: linear, quaternion column groups by slerp, angle columns wrapped to (-pi, pi]; the first or last
    row within half a ``period`` outside the span; None farther out, or inside a gap of more than
    ``gap_periods`` periods farther than half a period from both ends (used by Truth and TruthWindow)."""
    n = len(tl)
    if n == 0:
        return None
    half = 0.5 * period
    if t < tl[0]:
        row = rows[0].copy() if tl[0] - t <= half else None
    elif t >= tl[-1]:
        row = rows[n - 1].copy() if t - tl[-1] <= half else None
    else:
        i = bisect.bisect_right(tl, t)  # tl[i-1] <= t < tl[i]
        t0, t1 = tl[i - 1], tl[i]
        dt = t1 - t0
        if dt > gap_periods * period and min(t - t0, t1 - t) > half:
            return None
        f = (t - t0) / dt if dt > 0 else 1.0
        v0, v1 = rows[i - 1], rows[i]
        row = v0 + f * (v1 - v0)
        for cols in quaternions.values():
            row[cols] = _slerp(v0[cols], v1[cols], f)
    if row is not None:
        for c in angle_cols:
            row[c] = (row[c] + math.pi) % (2.0 * math.pi) - math.pi
    return row


class Truth:
    """The true state over time, from the ``truth`` messages of a recording.

    ``t`` (N,) sorted times (s); ``values`` (N, m) rows by ``names`` (block-prefixed element names).
    Quaternions (names ``Pw Px Py Pz`` for a prefix P) are normalised and interpolated by slerp; angle
    columns declared with ``with_angles`` are unwrapped and interpolated along the shorter way.
    ``at(t)`` is None outside the truth span by more than half the median sample period, and inside a gap
    of more than ``GAP_PERIODS`` sample periods farther than half a period from both ends.
    """

    GAP_PERIODS = 5.0

    def __init__(self, t: np.ndarray, values: np.ndarray, names: Sequence[str], angles: Collection[str] = ()):
        t = np.asarray(t, dtype=float).reshape(-1)
        values = np.asarray(values, dtype=float).reshape(t.size, len(names))
        order = np.argsort(t, kind="stable")
        self.t, self.values = t[order], values[order].copy()
        self.names: tuple[str, ...] = tuple(names)
        self.index: dict[str, int] = {n: i for i, n in enumerate(self.names)}
        self.angles = frozenset(a for a in angles if a in self.index)
        self.quaternions: dict[str, list[int]] = {}
        for n in self.names:
            if n.endswith("w") and all(n[:-1] + a in self.index for a in "xyz"):
                cols = [self.index[n[:-1] + a] for a in "wxyz"]
                self.quaternions[n[:-1]] = cols
                q = self.values[:, cols]
                nrm = np.linalg.norm(q, axis=1, keepdims=True)
                self.values[:, cols] = np.divide(q, nrm, out=q.copy(), where=nrm > 0)
        self._angle_cols = [self.index[a] for a in sorted(self.angles)]
        for c in self._angle_cols:
            self.values[:, c] = np.unwrap(self.values[:, c])
        self._quat_cols = [c for cols in self.quaternions.values() for c in cols]
        self.period = float(np.median(np.diff(self.t))) if self.t.size > 1 else 0.0
        self._tlist = self.t.tolist()

    @classmethod
    def from_messages(cls, messages: Sequence[Message], names: Sequence[str],
                      angles: Collection[str] = ()) -> "Truth":
        """Truth from the messages of sensor ``truth`` (others are ignored) with the column ``names`` of
        ``# fields truth ...``. Messages whose values are not ``len(names)`` numbers are skipped and counted
        in ``skipped``."""
        names = tuple(names)
        if not names:
            raise ValueError("truth needs its field names ('# fields truth px py ...' in the log header)")
        ts, rows, skipped = [], [], 0
        for m in messages:
            if m.sensor != "truth":
                continue
            try:
                v = m.floats()
            except ValueError:
                skipped += 1
                continue
            if v.shape != (len(names),) or not np.all(np.isfinite(v)) or not math.isfinite(m.t):
                skipped += 1
                continue
            ts.append(m.t)
            rows.append(v)
        truth = cls(np.array(ts), np.array(rows).reshape(len(rows), len(names)), names, angles)
        truth.skipped = skipped
        return truth

    skipped: int = 0

    @classmethod
    def from_recording(cls, path, stream: str = "truth") -> "Truth":
        """The ``truth`` (or ``reference``) lines of a recording file, whole (for studies and plots of
        short recordings; a run itself streams them through fusion.truth_stream)."""
        from fusion.logformat import ParsedStream, iter_messages
        from fusion.sources.recording import open_lines

        parsed = ParsedStream()
        msgs = [m for m in iter_messages(open_lines(path), parsed)
                if isinstance(m, Message) and m.sensor == stream]
        names = parsed.header.fields.get(stream)
        if not names:
            raise ValueError(f"{path}: no '# fields {stream} ...' header")
        return cls.from_messages(msgs, names) if stream == "truth" else cls.from_messages(
            [m._replace(sensor="truth") for m in msgs], names)

    def with_angles(self, names: Collection[str]) -> "Truth":
        """A copy whose columns ``names`` (rad) are angles: unwrapped for interpolation, wrapped on output."""
        return Truth(self.t, self.values, self.names, set(self.angles) | set(names))

    def __len__(self) -> int:
        return int(self.t.size)

    def __repr__(self) -> str:
        span = f"{self.t[0]:.3f}..{self.t[-1]:.3f} s" if len(self) else "empty"
        return f"Truth({len(self)} samples, {span}, fields {' '.join(self.names)})"

    @property
    def span(self) -> tuple[float, float] | None:
        return (float(self.t[0]), float(self.t[-1])) if len(self) else None

    def row(self, t: float) -> np.ndarray | None:
        """The interpolated truth row (m,) at time ``t`` (s), in ``names`` order, or None (see class)."""
        return interpolate_row(self._tlist, self.values, t, self.period, self.GAP_PERIODS, self.quaternions,
                               self._angle_cols)

    def at(self, t: float) -> dict[str, float] | None:
        """``{name: value}`` of the truth at time ``t`` (s), or None where truth is not defined."""
        row = self.row(t)
        return None if row is None else dict(zip(self.names, row.tolist()))

    def sample(self, times: np.ndarray) -> np.ndarray:
        """Rows (k, m) at ``times`` (k,); NaN rows where truth is not defined (for plots)."""
        out = np.full((len(times), len(self.names)), np.nan)
        for k, t in enumerate(np.asarray(times, dtype=float).tolist()):
            r = self.row(t)
            if r is not None:
                out[k] = r
        return out


# --------------------------------------------------------------------------- error tracker
def _group(layout: StateLayout, block: str, names: Sequence[str]) -> list[str]:
    """Element names of ``block`` if the layout has it, else those of ``names`` in the layout."""
    if block in layout:
        return list(layout.block(block).element_names())
    return [n for n in names if n in layout.names]


class _Acc:
    """Sum of squares and maximum of a scalar error."""

    __slots__ = ("n", "ss", "max")

    def __init__(self) -> None:
        self.n, self.ss, self.max = 0, 0.0, 0.0

    def add(self, e: float) -> None:
        self.n += 1
        self.ss += e * e
        self.max = max(self.max, abs(e))

    @property
    def rmse(self) -> float:
        return math.sqrt(self.ss / self.n)


class ErrorTracker:
    """Errors of a stream of estimates against truth, NEES and per-sensor NIS: the summary's ``errors``
    and ``consistency`` (DESIGN.md, outputs).

    :param layout: the state layout of the estimates.
    :param truth: the recording's truth, or None (then only NIS is tracked).
    :param settle_s: skip the first ``settle_s`` seconds (from the first time seen by ``add`` or
        ``add_nis(t=...)``) in the statistics; ``add`` still returns the errors.
    :param reasons: estimate reasons to evaluate (default all: ``update`` and ``output``).
    :param position: the elements of the position error (default the block ``p``), e.g. ``["px", "py"]``
        for a system whose accuracy is specified in the horizontal plane (paper 000's 2-D ABPS).
    :param nees_attitude: include each quaternion block in the NEES as a 3-dof attitude error
        ``dtheta = 2 vec(q_est^-1 (x) q_true)`` (rad, body frame) with covariance ``T P_qq T^T``,
        ``T = 2 [rows x,y,z of L(q_est^-1)]`` (first order; the radial direction of q drops out). With
        False the NEES covers only the non-quaternion elements truth has.

    NEES is over every state element truth names (``dof`` = their count, +3 per quaternion block),
    evaluated with the full joint covariance of those elements; a step whose covariance is not positive
    definite is skipped and counted (``nees_skipped``).
    """

    def __init__(self, layout: StateLayout, truth: Truth | None, settle_s: float = 0.0,
                 reasons: Collection[str] | None = None, nees_attitude: bool = True,
                 position: Sequence[str] | None = None, keep_nis_series: bool = True):
        self.layout = layout
        self._nees_attitude_wanted = nees_attitude
        self.position_elements = tuple(position) if position else None
        self.settle_s = float(settle_s)
        self.reasons = None if reasons is None else frozenset(reasons)
        self.nis = NisTracker(keep_series=keep_nis_series)
        self.nees_stat = ChiSquareStat()
        self._t_first: float | None = None
        self.truth = None
        self.compared = 0
        if truth is not None and len(truth):
            self.set_truth(truth)

    def set_truth(self, truth) -> None:
        """Compare against ``truth`` from now on: a ``Truth``, or a ``fusion.truth_stream.TruthWindow``
        filled as the run goes (anything with ``names``, ``index``, ``angles``, ``with_angles``, ``row``)."""
        layout = self.layout
        nees_attitude = self._nees_attitude_wanted
        angle_elems = [n for b in layout.blocks if b.kind == "angle" for n in b.element_names()]
        angles = [n for n in angle_elems if n in truth.index]
        self.truth = truth.with_angles(angles) if angles and not set(angles) <= truth.angles else truth
        tr = self.truth
        names = layout.names
        # quaternion blocks of the state whose four elements truth has
        self._quats: list[tuple[str, list[int], list[int]]] = []
        quat_elems: set[str] = set()
        for b in layout.blocks:
            en = b.element_names()
            if b.kind == "quaternion" and all(n in tr.index for n in en):
                self._quats.append((b.name, [layout.element_index(n) for n in en], [tr.index[n] for n in en]))
                quat_elems.update(en)
        self._elems = [n for n in names if n in tr.index]
        self._ex = np.array([layout.element_index(n) for n in self._elems], dtype=int)
        self._et = np.array([tr.index[n] for n in self._elems], dtype=int)
        self._wrap = np.array([n in angles for n in self._elems], dtype=bool)
        self._ess = np.zeros(len(self._elems))   # sums of squared element errors
        self._emax = np.zeros(len(self._elems))  # largest |element error|
        self._has_wrap = bool(self._wrap.any())
        self._quat_pos = [[self._elems.index(names[i]) for i in xi] for _, xi, _ in self._quats]

        def covered(group: list[str]) -> list[int] | None:
            return [self._elems.index(n) for n in group] if group and all(n in tr.index for n in group) else None

        self._pos = covered(list(self.position_elements) if self.position_elements
                            else _group(layout, "p", ("px", "py", "pz")))
        self._vel = covered(_group(layout, "v", ("vx", "vy", "vz")))
        self._acc = {k: _Acc() for k in ("position", "velocity", "attitude")}
        # NEES: vector/angle elements truth has (+ 3-dof attitude per quaternion block)
        self._nees_vec = np.array([layout.element_index(n) for n in self._elems if n not in quat_elems], dtype=int)
        self._nees_vec_pos = np.array([i for i, n in enumerate(self._elems) if n not in quat_elems], dtype=int)
        self.nees_attitude = nees_attitude and bool(self._quats)
        self.nees_dof = self._nees_vec.size + (3 * len(self._quats) if self.nees_attitude else 0)
        self._T = np.zeros((self.nees_dof, layout.n))
        self._T[np.arange(self._nees_vec.size), self._nees_vec] = 1.0

    # ------------------------------------------------------------------ per estimate
    def start(self, t: float) -> None:
        """Start the ``settle_s`` clock at ``t`` (s) unless it has started (a streaming run calls it with
        the first estimate's time, which may be compared against truth only later)."""
        if self._t_first is None:
            self._t_first = float(t)

    def _settled(self, t: float) -> bool:
        if self._t_first is None:
            self._t_first = t
        return t - self._t_first >= self.settle_s

    def add(self, estimate: Estimate) -> dict | None:
        """Errors of ``estimate`` against truth at its time, or None (no truth there, or a reason not
        evaluated). Returns ``{"t", "elements": {name: x_est - x_true}, "position_m", "velocity_mps",
        "attitude_deg", "nees", "nees_dof"}`` with only the keys that apply. Counted in the statistics
        unless within ``settle_s``."""
        if self.reasons is not None and estimate.reason not in self.reasons:
            return None
        t = float(estimate.t)
        settled = self._settled(t)
        if self.truth is None or not self._elems:
            return None
        row = self.truth.row(t)
        if row is None:
            return None
        x = np.asarray(estimate.belief.x, dtype=float)
        xt = row[self._et]
        # per quaternion block: (q_est unit, q_true aligned to the estimate's hemisphere), as float tuples
        quats = []
        for k, (_, xi, ti) in enumerate(self._quats):
            qe, qt = x[xi].tolist(), row[ti].tolist()
            if sum(a * b for a, b in zip(qe, qt)) < 0.0:
                qt = [-a for a in qt]
            xt[self._quat_pos[k]] = qt  # so the element errors of q are meaningful
            quats.append((qe, qt))
        e = x[self._ex] - xt
        if self._has_wrap:
            e[self._wrap] = (e[self._wrap] + math.pi) % (2.0 * math.pi) - math.pi
        el = e.tolist()
        out: dict = {"t": t, "elements": dict(zip(self._elems, el))}
        if self._pos is not None:
            out["position_m"] = math.sqrt(sum(el[i] * el[i] for i in self._pos))
        if self._vel is not None:
            out["velocity_mps"] = math.sqrt(sum(el[i] * el[i] for i in self._vel))
        dth = []
        if quats:
            ang = 0.0
            for qe, qt in quats:
                # d = q_est^-1 (x) q_true: its angle is that of q_true^-1 (x) q_est; 2 vec(d) ~ dtheta
                n = math.sqrt(sum(a * a for a in qe)) or 1.0
                d = _qmul_conj(qe, qt)
                w, v = abs(d[0]) / n, math.sqrt(d[1] ** 2 + d[2] ** 2 + d[3] ** 2) / n
                ang = max(ang, math.degrees(2.0 * math.atan2(v, w)))
                sgn = 2.0 / n if d[0] >= 0.0 else -2.0 / n
                dth.append(([a / n for a in qe], [sgn * d[1], sgn * d[2], sgn * d[3]]))
            out["attitude_deg"] = ang
        if self.nees_dof:
            out["nees"] = self._nees(estimate.belief.cov, e, dth)
            out["nees_dof"] = self.nees_dof
        if settled:
            self.compared += 1
            self._ess += e * e
            np.fmax(self._emax, np.abs(e), out=self._emax)
            for key, k in (("position", "position_m"), ("velocity", "velocity_mps"), ("attitude", "attitude_deg")):
                if k in out:
                    self._acc[key].add(out[k])
            if "nees" in out:
                self.nees_stat.add(out["nees"], self.nees_dof)
        return out

    def _nees(self, P: np.ndarray, e: np.ndarray, dth: list) -> float:
        idx = self._nees_vec
        if not self.nees_attitude:
            return nees(-e[self._nees_vec_pos], P[np.ix_(idx, idx)])
        # Reduce the state error to [vector elements; 3-dof attitude per quaternion]: err = T (x_true - x_est)
        nv = idx.size
        T = self._T  # vector rows are fixed selections; the quaternion rows are refilled each step
        err = np.empty(self.nees_dof)
        err[:nv] = -e[self._nees_vec_pos]
        r = nv
        for (qe, th), (_, xi, _) in zip(dth, self._quats):
            w, a, b, c = qe[0], -qe[1], -qe[2], -qe[3]  # q_est^-1 (unit)
            # rows x,y,z of L(q_est^-1) (L(a) b = a (x) b), doubled: dtheta = 2 vec(q_est^-1 (x) dq)
            T[r:r + 3, xi[0]:xi[0] + 4] = (2.0 * a, 2.0 * w, -2.0 * c, 2.0 * b), \
                (2.0 * b, 2.0 * c, 2.0 * w, -2.0 * a), (2.0 * c, -2.0 * b, 2.0 * a, 2.0 * w)
            err[r:r + 3] = th
            r += 3
        return nees(err, T @ P @ T.T)

    def add_nis(self, sensor: str, nis: float, dim: int, t: float | None = None) -> None:
        """Record the NIS of one update of ``sensor`` (measurement dimension ``dim``). Call it for every
        update tried, accepted or rejected by its gate (a gate truncates the distribution otherwise).
        With ``t`` it respects ``settle_s`` and keeps a series for plots (``nis_series``)."""
        if t is not None and not self._settled(float(t)):
            return
        self.nis.add(sensor if sensor is not None else "?", nis, dim, t)

    def nis_series(self) -> dict[str, tuple[np.ndarray, np.ndarray, int]]:
        """``{sensor: (times, values, dim)}`` of the NIS recorded with a time (for fusion.sinks.plot)."""
        return self.nis.series()

    # ------------------------------------------------------------------ summary
    def summary(self) -> dict:
        """``{"errors": {...}, "consistency": {...}}`` with the DESIGN.md keys that apply:

        errors: ``position_rmse_m``, ``position_max_m``, ``velocity_rmse_mps`` (+ ``velocity_max_mps``),
        ``attitude_rmse_deg``, ``attitude_max_deg``, plus ``element_rmse`` {element: RMSE in its SI unit,
        e.g. bias ``bax`` in m/s^2} and ``samples`` (estimates compared). Empty without truth.

        consistency: ``nees_mean``, ``nees_in_95_fraction``, ``nees_dof`` (+ ``nees_samples``,
        ``nees_skipped``) when truth covers some element; ``nis_mean``, ``nis_in_95_fraction``,
        ``nis_dof``, ``nis_samples`` as {sensor: value} (empty dicts when no NIS was recorded).
        """
        errors: dict = {}
        if self.truth is not None and self.compared:
            p, v, a = self._acc["position"], self._acc["velocity"], self._acc["attitude"]
            if p.n:
                errors["position_rmse_m"] = p.rmse
                errors["position_max_m"] = p.max
            if v.n:
                errors["velocity_rmse_mps"] = v.rmse
                errors["velocity_max_mps"] = v.max
            if a.n:
                errors["attitude_rmse_deg"] = a.rmse
                errors["attitude_max_deg"] = a.max
            errors["element_rmse"] = dict(zip(self._elems, np.sqrt(self._ess / self.compared).tolist()))
            errors["samples"] = self.compared
        consistency: dict = {}
        st = self.nees_stat
        if st.count or st.skipped:
            consistency.update(nees_mean=st.mean, nees_in_95_fraction=st.in_fraction, nees_dof=self.nees_dof,
                               nees_samples=st.count, nees_skipped=st.skipped)
        consistency.update(self.nis.summary())
        return {"errors": errors, "consistency": consistency}
