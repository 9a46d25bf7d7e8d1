"""The run's start-up (:class:`StartUp`): the first belief from the configured one, a static-start alignment
(the process model's Aligns capability, then every AlignsState measurement model) and the fixes of
``initial.from_sensor`` before the start (through the model's PositionFromFix capability when it has one).

The initial position: when the alignment window was judged static (the process model's ChecksStillness),
every fix taken in it measures the same position, so they are combined (:func:`combine_fixes`: outliers
against the others refused by their own covariances, then the covariance-weighted mean); otherwise (no
static window, a window in flight, a process that cannot tell) the latest fix, the one nearest the start.
A window judged moving is a ``warning`` (the numbers, and the summary's ``health``), the gyro bias prior is
kept (the model's ``align(still=False)``) and the velocity prior widened to the speed the fixes show."""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from fusion.api import Aligns, ChecksStillness, Event, PositionFromFix, has
from fusion.chisquare import chi2

#: Probability of the test that refuses a fix of the static window against the others (as a chi2 gate's).
FIX_INLIER_PROBABILITY = 0.999
#: Fixes of ``initial.from_sensor`` kept before the start (the latest; a bound on memory if it never starts).
FIXES_MAX = 1000


def combine_fixes(zs: np.ndarray, Rs: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """One position from ``N`` fixes ``zs`` (N, k) of a static receiver with covariances ``Rs`` (N, k, k) (or
    None: unknown): ``(z (k,), P (k, k) or None, inliers (N,) bool)``.

    Robust: each fix is tested against the per-axis median of all (its Mahalanobis distance by its own R,
    chi-square on k dof at :data:`FIX_INLIER_PROBABILITY`), then again against the covariance-weighted mean
    of the fixes kept; the result is the covariance-weighted mean of the inliers (no inlier: the fix
    nearest the median alone). Without covariances: the per-axis median of all, P None.

    P is NOT (sum R_i^-1)^-1 (that is R / N for N like fixes): consecutive fixes of a standing receiver
    share much of their error (the assumed height of a 2-D fix, the beacons' survey, the speed of sound,
    multipath of one unchanged geometry, a GNSS's slowly varying atmospheric error), and how much is not
    known here. P is the covariance of the weighted mean when the fixes' errors are fully correlated,
    e_i = L_i xi with L_i L_i^T = R_i and one xi: P = S S^T, S = sum_i W_i L_i (W_i the mean's weights). It
    is R for N fixes of one R, and never below what each fix claims for itself (an origin fix already
    averaged, R / N, keeps its R / N): honest whatever the correlation, the gain of combining being the
    outliers refused and the independent part averaged out, not a claimed sd."""
    zs = np.asarray(zs, dtype=float)
    n, k = zs.shape
    med = np.median(zs, axis=0)
    if Rs is None:
        return med, None, np.ones(n, dtype=bool)
    Rs = np.asarray(Rs, dtype=float)
    Ri = np.linalg.inv(Rs)
    limit = chi2.ppf(FIX_INLIER_PROBABILITY, k)

    def dist2(c: np.ndarray) -> np.ndarray:
        e = zs - c
        return np.einsum("ni,nij,nj->n", e, Ri, e)

    def mean(keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        info = Ri[keep].sum(axis=0)
        return np.linalg.solve(info, np.einsum("nij,nj->i", Ri[keep], zs[keep])), info

    d2 = dist2(med)
    keep = d2 <= limit
    if not keep.any():
        keep = d2 == d2.min()
    m, _ = mean(keep)
    again = dist2(m) <= limit
    if again.any() and not np.array_equal(again, keep):
        keep = again
        m, _ = mean(keep)
    _, info = mean(keep)
    W = np.linalg.solve(info, Ri[keep])                  # (n_keep, k, k): the weights, summing to I
    S = np.einsum("nij,njl->il", W, np.linalg.cholesky(Rs[keep]))
    return m, S @ S.T, keep


class StartUp:
    """The start-up state machine: it gathers the static start's input samples (``window``) and the fixes of
    ``initial.from_sensor`` (``take_fix``) until the first belief can be made (``start``). ``aligners``: per
    sensor whose model aligns part of the state (AlignsState), its observations of the window. Warnings and the
    ``initial`` event go to ``tally`` (fusion.run.tally), handed on with the first prediction's events."""

    def __init__(self, system, filter_, process, aligners: list[str], sensors: dict, tally):
        spec = system.spec
        self.layout = system.layout
        self.filter, self.process, self.sensors, self.tally = filter_, process, sensors, tally
        self._x0 = system.x0.copy()
        self._P0 = system.P0.copy()
        self.align_s = spec.initial.align_s
        self.from_sensor = spec.initial.from_sensor
        self.have_fix = self.from_sensor is None
        self._align_u: list[np.ndarray] = []
        self._align_t: list[float] = []
        self._align_t0: float | None = None
        # The fixes of initial.from_sensor before the start, and the window's verdict (ChecksStillness: True
        # static, False moving, None not judged): a static window's fixes are combined.
        self._fixes: deque = deque(maxlen=FIXES_MAX)
        self.still: bool | None = None   # the static window's verdict (public: the start-up's state)
        self.alignment_not_static: str | None = None   # why the window was judged moving (summary health)
        self.aligners: dict[str, list] = {n: [] for n in aligners}
        self._stillness = process.stillness if has(process, ChecksStillness) else None
        self._aligns = has(process, Aligns)

    def start(self, t: float):
        """The first belief, at ``t``: the configured one, aligned and with the remembered fix if any."""
        belief = self.filter.initial_belief(t, *self.initial())
        if belief.events:   # a repaired initial covariance (srukf): reported with the first prediction's
            self.tally.reported(belief.events)
            belief = belief.with_(events=())
        return belief

    def window(self, good: list[tuple[float, np.ndarray]], sensor: str) -> tuple[int, int | None]:
        """Before the first belief: gather the static start's samples ``good`` ((t s, u) of the input ``sensor``).
        Returns ``(samples gathered, i)``: ``i`` the index of the sample at which the window closed (the belief
        starts there: ``start(t_i)``), None while it is open."""
        for i, (t, u) in enumerate(good):
            if self._align_t0 is None:
                self._align_t0 = t
            if t - self._align_t0 < self.align_s or not self.have_fix:
                self._align_u.append(u)
                self._align_t.append(t)
                continue
            if self.align_s and self._align_u:
                self._align(t, sensor)
            return i, i
        return len(good), None

    def _align(self, t: float, sensor: str) -> None:
        us, ts = np.asarray(self._align_u, dtype=float), np.asarray(self._align_t, dtype=float)
        u_mean = np.mean(us, axis=0)
        if self._stillness is not None:
            verdict = self._stillness(self._x0, self._P0, us, ts)
            self.still = None if verdict is None else bool(verdict[0])
            if verdict is not None and not verdict[0]:
                self._not_static(t, sensor, verdict[1])
            self._x0, self._P0 = self.process.align(self._x0, self._P0, u_mean,
                                                    still=self.still is not False, window=(us, ts))
        elif self._aligns:   # wiring refuses align_s for a process without it
            self._x0, self._P0 = self.process.align(self._x0, self._P0, u_mean)
        for name, observations in self.aligners.items():
            if self.still is not True:   # not a static window (in flight): only its last align_s s
                observations = [o for o in observations if o.t >= t - self.align_s] or observations[-1:]
            # called with no observations too (no sample of the sensor in the window): the model then knows
            # the static start is over and can refuse its later messages with the reason
            s = self.sensors[name]
            self._x0, self._P0 = s.model.align_state(self._x0, self._P0, u_mean, observations, s.R)

    def _not_static(self, t: float, sensor: str, why: str) -> None:
        """The alignment window judged moving (``why``: the process model's numbers and what it keeps): a
        ``warning`` with the first prediction, and the summary's ``health``."""
        self.alignment_not_static = why
        fixes = (f"; the initial position is the latest fix of {self.from_sensor!r} and the velocity prior is "
                 "widened to the speed its fixes show") if self.from_sensor else ""
        self.tally.add(Event(t, "warning", sensor, f"alignment: the static start (initial.align_s "
                             f"{self.align_s:g} s) is not static: {why}{fixes}"))

    def start_without_fix(self) -> None:
        """Start without waiting for ``initial.from_sensor`` (the recording has no such stream): the position and
        velocity from the configured prior, the rest aligned as usual."""
        self.from_sensor = None
        self.have_fix = True

    def take_fix(self, obs) -> None:
        """Remember a fix of ``initial.from_sensor`` for the initial position (module doc: combined when the
        window was static, else the latest)."""
        self._fixes.append(obs)
        self.have_fix = True

    @property
    def latest_fix(self):
        """The latest fix of ``initial.from_sensor`` taken before the start (None when none was)."""
        return self._fixes[-1] if self._fixes else None

    def _fix_for_start(self) -> tuple[object | None, np.ndarray | None, np.ndarray | None]:
        """``(obs, z, R)``: the fix that sets the initial position, with its values and covariance (None when
        it carries none). A static window's fixes combined (:func:`combine_fixes`, told in an ``initial``
        event) into the latest fix's position part (the rest of the latest fix as it is, uncorrelated with
        it); otherwise the latest fix's own."""
        if not self._fixes:
            return None, None, None
        obs = self._fixes[-1]
        z = np.array(obs.z, dtype=float)
        R = None if obs.R is None else np.array(obs.R, dtype=float)
        k = min(len(z), self.layout["p"].stop - self.layout["p"].start)
        same = [f for f in self._fixes if len(f.z) >= k and (f.R is None) == (R is None)]
        if self.still is not True or len(same) < 2:
            return obs, z, R
        zs = np.array([np.asarray(f.z, dtype=float)[:k] for f in same])
        Rs = None if R is None else np.array([np.asarray(f.R, dtype=float)[:k, :k] for f in same])
        try:
            zc, Pc, keep = combine_fixes(zs, Rs)
        except np.linalg.LinAlgError:       # a singular fix covariance: the latest fix, as without a static window
            return obs, z, R
        z[:k] = zc
        if R is not None:
            R[:k, :] = 0.0
            R[:, :k] = 0.0
            R[:k, :k] = Pc
        out = [f"{f.t:.3f} s" for f, kept in zip(same, keep) if not kept]
        self.tally.add(Event(obs.t, "initial", self.from_sensor, (
            f"initial position from {int(keep.sum())} of the {len(same)} fixes of the static start"
            + (f" (covariance-weighted mean; refused against the others: {', '.join(out)})" if out else
               " (covariance-weighted mean)" if R is not None else " (per-axis median)"))))
        return obs, z, R

    def initial(self) -> tuple[np.ndarray, np.ndarray]:
        """x0, P0 with the position block from the remembered fix. A model with ``position_from`` (a
        position with a lever arm) turns the fix's position into the state's at the initial attitude.
        Values of the fix beyond the position (a GPS fix's velocity) set the state elements their rows of
        h select (a row of the model's analytic dh/dx that is a unit vector); rows that are not a plain
        selection, or a model without an analytic Jacobian, leave those elements to the first update."""
        x0, P0 = self._x0.copy(), self._P0.copy()
        obs, z, R = self._fix_for_start()
        if obs is None:
            return x0, P0
        if self.still is False:
            P0 = self._moving_velocity(P0)
        sl = self.layout["p"]
        k = min(len(z), sl.stop - sl.start)
        to_state = obs.model.position_from if has(obs.model, PositionFromFix) else None
        x0[sl.start:sl.start + k] = to_state(z, x0)[:k] if to_state else z[:k]
        rows, cols = list(range(k)), list(range(sl.start, sl.start + k))
        H = obs.model.jacobian(x0) if len(z) > k else None   # the model's analytic dh/dx (None: none)
        if H is not None:
            H = np.atleast_2d(H)
            for i in range(k, len(z)):
                j = int(np.argmax(np.abs(H[i])))
                if abs(H[i, j] - 1.0) < 1e-6 and np.sum(np.abs(H[i])) < 1.0 + 1e-6 and j not in cols:
                    x0[j] = z[i]
                    rows.append(i)
                    cols.append(j)
        if R is not None:
            idx = np.array(cols)
            P0[idx, :] = 0.0
            P0[:, idx] = 0.0
            P0[np.ix_(idx, idx)] = R[np.ix_(rows, rows)]
        return x0, P0

    def _moving_velocity(self, P0: np.ndarray) -> np.ndarray:
        """P0 with the velocity variances (a ``v`` block) raised to the squared mean speed of the window's
        fixes (first to last): a prior of a vehicle at rest is no prior for one that drove, and the speed is
        what the fixes show of it; the fixes after the start then give the velocity."""
        layout = self.layout
        if "v" not in layout or len(self._fixes) < 2:
            return P0
        first, last = self._fixes[0], self._fixes[-1]
        if not last.t > first.t:
            return P0
        k = min(len(first.z), len(last.z), layout["p"].stop - layout["p"].start)
        moved = np.asarray(last.z, dtype=float)[:k] - np.asarray(first.z, dtype=float)[:k]
        speed = float(np.linalg.norm(moved) / (last.t - first.t))      # m/s
        if not math.isfinite(speed):
            return P0
        P0 = P0.copy()
        i = np.arange(layout["v"].start, layout["v"].stop)
        P0[i, i] = np.maximum(P0[i, i], speed * speed)
        return P0
