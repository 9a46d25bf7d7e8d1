"""The scheduler's initialisation: the first belief from the configured one, a static-start alignment
(the process model's Aligns capability, then every AlignsState measurement model) and the fixes of
``initial.from_sensor`` before the start (through the model's PositionFromFix capability when it has one).
A mixin of fusion.scheduler.Scheduler, whose attributes it uses.

The initial position: when the alignment window was judged static (the process model's ChecksStillness),
every fix taken in it measures the same position, so they are combined (:func:`combine_fixes`: outliers
against the others refused by their own covariances, then the covariance-weighted mean); otherwise (no
static window, a window in flight, a process that cannot tell) the latest fix, the one nearest the start.
A window judged moving is a ``warning`` (the numbers, and the summary's ``health``), the gyro bias prior is
kept (the model's ``align(still=False)``) and the velocity prior widened to the speed the fixes show."""
from __future__ import annotations

import math

import numpy as np

from fusion.api import Aligns, ChecksStillness, Event, PositionFromFix, has
from fusion.chisquare import chi2
from fusion.config import SensorRuntime

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


class Initialisation:
    """Mixin: ``_start``, ``_align``, ``_take_fix``, ``_initial`` (see fusion.scheduler)."""

    def _start(self, t: float) -> None:
        """The first belief, at ``t``: the configured one, aligned and with the remembered fix if any."""
        belief = self.filter.initial_belief(t, *self._initial())
        if belief.events:   # a repaired initial covariance (srukf): reported with the first prediction's
            for e in belief.events:
                self.filter_counters[e.kind] += 1
            self._filter_events.extend(belief.events)
            belief = belief.with_(events=())
        self.belief = belief
        self._next_output = t + self.output_dt if self.output_dt else math.inf

    def _align(self, good: list[tuple[float, np.ndarray]], sensor: SensorRuntime) -> list[tuple[float, np.ndarray]]:
        """Before the first belief: gather the static start; create the belief once aligned (and fixed).
        Returns the samples left to integrate after the belief exists."""
        for i, (t, u) in enumerate(good):
            if self._align_t0 is None:
                self._align_t0 = t
            if t - self._align_t0 < self._align_s or not self._have_fix:
                self._align_u.append(u)
                self._align_t.append(t)
                sensor.counters["used"] += 1
                continue
            if self._align_s and self._align_u:
                us, ts = np.asarray(self._align_u, dtype=float), np.asarray(self._align_t, dtype=float)
                u_mean = np.mean(us, axis=0)
                if has(self.process, ChecksStillness):
                    verdict = self.process.stillness(self._x0, self._P0, us, ts)
                    self._still = None if verdict is None else bool(verdict[0])
                    if verdict is not None and not verdict[0]:
                        self._not_static(t, sensor.name, verdict[1])
                    self._x0, self._P0 = self.process.align(self._x0, self._P0, u_mean,
                                                            still=self._still is not False, window=(us, ts))
                elif has(self.process, Aligns):   # wiring refuses align_s for a process without it
                    self._x0, self._P0 = self.process.align(self._x0, self._P0, u_mean)
                for name, observations in self._aligners.items():
                    if self._still is not True:   # not a static window (in flight): only its last align_s s
                        observations = [o for o in observations if o.t >= t - self._align_s] or observations[-1:]
                    # called with no observations too (no sample of the sensor in the window): the model
                    # then knows the static start is over and can refuse its later messages with the reason
                    s = self.sensors[name]
                    self._x0, self._P0 = s.model.align_state(self._x0, self._P0, u_mean, observations, s.R)  # type: ignore[union-attr]
            self._start(t)
            self.u, self._u_t = u, t
            sensor.counters["used"] += 1
            return good[i + 1:]
        return []

    def _not_static(self, t: float, sensor: str, why: str) -> None:
        """The alignment window judged moving (``why``: the process model's numbers and what it keeps): a
        ``warning`` with the first prediction, and the summary's ``health``."""
        self.alignment_not_static = why
        fixes = (f"; the initial position is the latest fix of {self._from_sensor!r} and the velocity prior is "
                 "widened to the speed its fixes show") if self._from_sensor else ""
        self._filter_events.append(Event(t, "warning", sensor, f"alignment: the static start (initial.align_s "
                                         f"{self._align_s:g} s) is not static: {why}{fixes}"))

    def start_without_fix(self, output_hz: float | None = None) -> None:
        """Start without waiting for ``initial.from_sensor`` (the recording has no such stream): the position
        and velocity from the configured prior, the rest aligned as usual; ``output_hz``: estimates by
        prediction at that rate when the config has none (a recording that may have no update to emit at)."""
        self._from_sensor = None
        self._have_fix = True
        if output_hz and not self.output_dt:
            self.output_dt = 1.0 / output_hz

    def _take_fix(self, obs) -> None:
        """Remember a fix of ``initial.from_sensor`` for the initial position (module doc: combined when the
        window was static, else the latest)."""
        self._fixes.append(obs)
        self._fix = obs          # the latest
        self._have_fix = True

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
        k = min(len(z), self.system.layout["p"].stop - self.system.layout["p"].start)
        same = [f for f in self._fixes if len(f.z) >= k and (f.R is None) == (R is None)]
        if self._still is not True or len(same) < 2:
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
        self._filter_events.append(Event(obs.t, "initial", self._from_sensor, (
            f"initial position from {int(keep.sum())} of the {len(same)} fixes of the static start"
            + (f" (covariance-weighted mean; refused against the others: {', '.join(out)})" if out else
               " (covariance-weighted mean)" if R is not None else " (per-axis median)"))))
        return obs, z, R

    def _initial(self) -> tuple[np.ndarray, np.ndarray]:
        """x0, P0 with the position block from the remembered fix. A model with ``position_from`` (a
        position with a lever arm) turns the fix's position into the state's at the initial attitude.
        Values of the fix beyond the position (a GPS fix's velocity) set the state elements their rows of
        h select (a row of the model's analytic dh/dx that is a unit vector); rows that are not a plain
        selection, or a model without an analytic Jacobian, leave those elements to the first update."""
        x0, P0 = self._x0.copy(), self._P0.copy()
        obs, z, R = self._fix_for_start()
        if obs is None:
            return x0, P0
        if self._still is False:
            P0 = self._moving_velocity(P0)
        sl = self.system.layout["p"]
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
        layout = self.system.layout
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
