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
(linear interpolation). An estimate with a non-finite error (NaN after the filter diverged) is left out of
the statistics and counted (``nonfinite_samples``): RMSE, max and ``samples`` are over the finite ones. When a run emits both fixed-rate outputs and per-update estimates, both count, so
the RMSE weights the more frequent kind more; pass ``reasons={"output"}`` to evaluate only one kind.
"""
from __future__ import annotations

import math
from typing import Collection, Sequence

import numpy as np

from fusion import quaternion as quat
from fusion.api import Estimate, StateLayout
from fusion.consistency import ChiSquareStat, NisTracker, nees

__all__ = ["Truth", "ErrorTracker", "attitude_error_deg", "interpolate_row"]

from fusion.truth import Truth, interpolate_row  # noqa: E402 (re-exported: the truth table moved there)


# --------------------------------------------------------------------------- attitude error
def attitude_error_deg(q_true: np.ndarray, q_est: np.ndarray) -> np.ndarray:
    """Rotation angle (deg, in [0, 180]) of ``q_true^-1 (x) q_est`` for quaternions (..., 4), scalar first.
    Neither needs unit norm; ``q`` and ``-q`` give the same angle."""
    d = quat.multiply(quat.conjugate(np.asarray(q_true, float)), np.asarray(q_est, float))
    return np.degrees(2.0 * np.arctan2(np.linalg.norm(d[..., 1:], axis=-1), np.abs(d[..., 0])))



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
        self.compared = 0     # estimates in the error statistics (settled, truth there, errors finite)
        self.nonfinite = 0    # settled estimates with truth left out for a non-finite error
        if truth is not None and len(truth):
            self.set_truth(truth)

    def position_group(self) -> list[str]:
        """The state elements whose error is the position error (``position`` or the block ``p``)."""
        if self.position_elements:
            return list(self.position_elements)
        return _group(self.layout, "p", ("px", "py", "pz"))

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

        self._pos = covered(self.position_group())
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
        unless within ``settle_s``. (:meth:`locate` then :meth:`score` of that one estimate.)"""
        item = self.locate(estimate)
        if item is None:
            return None
        return self.score([item])[0][0]  # type: ignore[index]

    def locate(self, estimate: Estimate) -> tuple | None:
        """The first half of :meth:`add`, what must be taken when the estimate is evaluated: whether it is
        settled (this starts the settle clock as ``add`` does) and where truth is at its time (a truth
        window's ``locate``: its samples and fraction; another truth's row). None when it is not evaluated
        (a reason not evaluated, no truth there). :meth:`score` does the arithmetic later, for many at once."""
        if self.reasons is not None and estimate.reason not in self.reasons:
            return None
        t = float(estimate.t)
        settled = self._settled(t)
        if self.truth is None or not self._elems:
            return None
        locate = getattr(self.truth, "locate", None)
        where = self.truth.row(t) if locate is None else locate(t)
        if where is None:
            return None
        return (estimate, t, settled, where)

    def score(self, items: Sequence[tuple], want: bool = True) -> tuple[list[dict] | None, np.ndarray]:
        """The second half of :meth:`add` for the :meth:`locate` results ``items``, in their order: the
        statistics updated as by one ``add`` each (the same numbers to the last bit: the arithmetic is
        elementwise over the batch, the running sums accumulate in order, and each NEES is its own
        Cholesky), and ``(the errors dicts, or None without want, the truth rows (k, m))``."""
        k = len(items)
        wheres = [it[3] for it in items]
        if all(w.__class__ is tuple for w in wheres):
            rows = self.truth.rows(wheres)  # type: ignore[union-attr]
        else:
            rows = np.array([w if w.__class__ is not tuple else self.truth.rows([w])[0]  # type: ignore[union-attr]
                             for w in wheres], dtype=float)
        X = np.array([it[0].belief.x for it in items], dtype=float).reshape(k, -1)
        XT = rows[:, self._et]
        xl, rl = X.tolist(), rows.tolist()
        # per estimate and quaternion block: (q_est, q_true aligned to the estimate's hemisphere) as floats
        quats: list[list[tuple[list[float], list[float]]]] = []
        for j in range(k):
            qs = []
            for q, (_, xi, ti) in enumerate(self._quats):
                qe, qt = [xl[j][i] for i in xi], [rl[j][i] for i in ti]
                if sum(a * b for a, b in zip(qe, qt)) < 0.0:
                    qt = [-a for a in qt]
                    XT[j, self._quat_pos[q]] = qt  # so the element errors of q are meaningful
                qs.append((qe, qt))
            quats.append(qs)
        E = X[:, self._ex] - XT
        if self._has_wrap:
            E[:, self._wrap] = (E[:, self._wrap] + math.pi) % (2.0 * math.pi) - math.pi
        EL = E.tolist()
        finite = np.isfinite(E).all(axis=1).tolist()
        pos, vel = self._pos, self._vel
        found: list[tuple[float | None, float | None, float | None]] = []
        dths: list[list] = []
        for j in range(k):
            el = EL[j]
            p = math.sqrt(sum(el[i] * el[i] for i in pos)) if pos is not None else None
            v = math.sqrt(sum(el[i] * el[i] for i in vel)) if vel is not None else None
            ang = None
            dth = []
            if quats[j]:
                ang = 0.0
                for qe, qt in quats[j]:
                    # d = q_est^-1 (x) q_true: its angle is that of q_true^-1 (x) q_est; 2 vec(d) ~ dtheta
                    n = math.sqrt(sum(a * a for a in qe)) or 1.0
                    d = quat.conj_multiply_floats(qe, qt)
                    w, vv = abs(d[0]) / n, math.sqrt(d[1] ** 2 + d[2] ** 2 + d[3] ** 2) / n
                    ang = max(ang, math.degrees(2.0 * math.atan2(vv, w)))
                    sgn = 2.0 / n if d[0] >= 0.0 else -2.0 / n
                    dth.append(([a / n for a in qe], [sgn * d[1], sgn * d[2], sgn * d[3]]))
            found.append((p, v, ang))
            dths.append(dth)
        nees_values = self._nees(items, E, dths) if self.nees_dof else None
        outs: list[dict] | None = [] if want else None
        compared = []
        acc = self._acc
        for j in range(k):
            p, v, ang = found[j]
            settled = items[j][2]
            if settled and not finite[j]:
                # a diverged filter's estimate: left out of the errors (counted), so RMSE, max and samples
                # are over the same finite estimates; its NaN NEES is counted skipped
                self.nonfinite += 1
                if nees_values is not None:
                    self.nees_stat.add(nees_values[j], self.nees_dof)
            elif settled:
                self.compared += 1
                compared.append(j)
                for key, value in (("position", p), ("velocity", v), ("attitude", ang)):
                    if value is not None:
                        acc[key].add(value)
                if nees_values is not None:
                    self.nees_stat.add(nees_values[j], self.nees_dof)
            if outs is not None:
                out: dict = {"t": items[j][1], "elements": dict(zip(self._elems, EL[j]))}
                if p is not None:
                    out["position_m"] = p
                if v is not None:
                    out["velocity_mps"] = v
                if ang is not None:
                    out["attitude_deg"] = ang
                if nees_values is not None:
                    out["nees"] = nees_values[j]
                    out["nees_dof"] = self.nees_dof
                outs.append(out)
        if compared:
            Ec = E[compared]
            # in order, as a running += per estimate: the same sums to the last bit
            self._ess = np.add.accumulate(np.concatenate([self._ess[None], Ec * Ec]), axis=0)[-1]
            np.fmax(self._emax, np.abs(Ec).max(axis=0), out=self._emax)
        return outs, rows

    def _nees(self, items: Sequence[tuple], E: np.ndarray, dths: list) -> list[float]:
        """NEES of each estimate of ``items`` (errors ``E`` (k, elements), attitude errors ``dths``)."""
        k = len(items)
        idx = self._nees_vec
        P = np.array([it[0].belief.cov for it in items], dtype=float).reshape(k, self.layout.n, self.layout.n)
        err = np.empty((k, self.nees_dof))
        nv = idx.size
        err[:, :nv] = -E[:, self._nees_vec_pos]
        if not self.nees_attitude:
            sub = P[:, idx[:, None], idx]
            return [nees(err[j], sub[j]) for j in range(k)]
        # Reduce the state error to [vector elements; 3-dof attitude per quaternion]: err = T (x_true - x_est)
        # with T's vector rows fixed selections and its quaternion rows from each estimate's attitude
        T = np.repeat(self._T[None], k, axis=0)
        r = nv
        for q, (_, xi, _) in enumerate(self._quats):
            block = []
            for j in range(k):
                qe = dths[j][q][0]
                w, a, b, c = qe[0], -qe[1], -qe[2], -qe[3]  # q_est^-1 (unit)
                # rows x,y,z of L(q_est^-1) (L(a) b = a (x) b), doubled: dtheta = 2 vec(q_est^-1 (x) dq)
                block.append(((2.0 * a, 2.0 * w, -2.0 * c, 2.0 * b), (2.0 * b, 2.0 * c, 2.0 * w, -2.0 * a),
                              (2.0 * c, -2.0 * b, 2.0 * a, 2.0 * w)))
            T[:, r:r + 3, xi[0]:xi[0] + 4] = block
            err[:, r:r + 3] = [dths[j][q][1] for j in range(k)]
            r += 3
        # one matrix product per estimate, as T @ P @ T.T (numpy's matmul calls the same BLAS per stacked pair)
        M = np.matmul(np.matmul(T, P), T.transpose(0, 2, 1))
        return [nees(err[j], M[j]) for j in range(k)]

    def add_nis(self, sensor: str, nis: float, dim: int, t: float | None = None,
                accepted: bool | None = None) -> None:
        """Record the NIS of one update of ``sensor`` (measurement dimension ``dim``). Call it for every
        update tried, accepted or rejected by its gate (a gate truncates the distribution otherwise), with
        ``accepted`` when known: the summary then gives the accepted and rejected ones apart as well
        (fusion.consistency.NisTracker.summary). With ``t`` it respects ``settle_s`` and keeps a series
        for plots (``nis_series``)."""
        if t is not None and not self._settled(float(t)):
            return
        self.nis.add(sensor if sensor is not None else "?", nis, dim, t, accepted)

    def nis_series(self) -> dict[str, tuple[np.ndarray, np.ndarray, int]]:
        """``{sensor: (times, values, dim)}`` of the NIS recorded with a time (for fusion.sinks.plot)."""
        return self.nis.series()

    # ------------------------------------------------------------------ summary
    def summary(self) -> dict:
        """``{"errors": {...}, "consistency": {...}}`` with the DESIGN.md keys that apply:

        errors: ``position_rmse_m``, ``position_max_m``, ``velocity_rmse_mps`` (+ ``velocity_max_mps``),
        ``attitude_rmse_deg``, ``attitude_max_deg``, plus ``element_rmse`` {element: RMSE in its SI unit,
        e.g. bias ``bax`` in m/s^2} and ``samples`` (estimates compared). Estimates with a non-finite
        error (a diverged filter) are left out of all of them and counted in ``nonfinite_samples`` (only
        when there are any; then ``samples`` is given even when it is 0). Empty without truth.

        consistency: ``nees_mean``, ``nees_in_95_fraction``, ``nees_dof`` (+ ``nees_samples``,
        ``nees_skipped``) when truth covers some element; ``nis_mean``, ``nis_in_95_fraction``,
        ``nis_dof``, ``nis_samples`` as {sensor: value} (empty dicts when no NIS was recorded), over every
        update tried; with ``accepted`` given to ``add_nis``, the ``nis_accepted_*`` and ``nis_rejected_*``
        keys of fusion.consistency.NisTracker.summary too.
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
        if self.truth is not None and self.nonfinite:
            errors["samples"] = self.compared
            errors["nonfinite_samples"] = self.nonfinite
        consistency: dict = {}
        st = self.nees_stat
        if st.count or st.skipped:
            consistency.update(nees_mean=st.mean, nees_in_95_fraction=st.in_fraction, nees_dof=self.nees_dof,
                               nees_samples=st.count, nees_skipped=st.skipped)
        consistency.update(self.nis.summary())
        return {"errors": errors, "consistency": consistency}
