"""Solver ``ols_trilateration``: a position fix from one cycle of beacon ranges (paper 000 sec. IV, eqs. 17-32).

The pure function :func:`trilaterate` does one fix (used by tests and initialisers); the component
:class:`OlsTrilateration` is the sensor preprocessor that gathers a cycle of ``beacon range`` messages
and emits one fix message with its covariance.
"""
from __future__ import annotations

import math
from typing import Any, ClassVar, Literal, Sequence

import numpy as np
from pydantic import Field
from scipy.linalg import cho_factor, cho_solve, qr, solve_triangular
from scipy.linalg.lapack import dpotrf as _dpotrf, dpotrs as _dpotrs
from fusion.chisquare import chi2

from fusion.api import MAX_MAGNITUDE, BuildContext, ConfigError, Event, MalformedMessage, Message, Params, Solver

REASONS = ("too_few_beacons", "degenerate", "inconsistent")
MAX_SD_M = 1e6   # m (m/s^2 for accel_sd): its square must stay finite through the fix covariance; no sensor is worse


class NoFix(ValueError):
    """No fix from these ranges; ``reason`` is one of ``too_few_beacons``, ``degenerate``, ``inconsistent``."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


def _solve_linear(B: np.ndarray, r: np.ndarray, dim: int, z: float, ref: int,
                  qr_condition: float, degenerate_condition: float) -> tuple[np.ndarray, np.ndarray, dict]:
    """OLS/QR solution of eqs. 25-32 with beacon ``ref`` as the reference point; returns the position (3,),
    the gain G (dim, k) from ranges to position (first order) and info."""
    k = len(r)
    others = [i for i in range(k) if i != ref]
    D = B[others] - B[ref]                                    # B_i - B_ref (k-1, 3)
    A = D[:, :dim]                                            # eq. 28 (the factor 2 moved into b, eq. 25)
    b = 0.5 * (r[ref] ** 2 - r[others] ** 2 + (D * D).sum(axis=1))        # eqs. 25-26, 30
    if dim == 2:
        b = b - D[:, 2] * (z - B[ref, 2])                     # known height: its term moves to b
    AtA = A.T @ A
    if dim == 2:                       # eigenvalues of the symmetric 2 x 2 A^T A in closed form (an SVD: ~10 us)
        h = 0.5 * (AtA[0, 0] + AtA[1, 1])
        e = math.sqrt(max(h * h - (AtA[0, 0] * AtA[1, 1] - AtA[0, 1] * AtA[1, 0]), 0.0))
        lo, hi = h - e, h + e
        cond = np.inf if lo <= hi * 1e-300 else hi / lo                  # cond(A^T A)
    else:
        sv = np.linalg.svd(A, compute_uv=False)
        cond = np.inf if sv[-1] <= sv[0] * 1e-300 else float((sv[0] / sv[-1]) ** 2)
    if not cond <= degenerate_condition:
        raise NoFix("degenerate", f"cond(A^T A) = {cond:.3g} > {degenerate_condition:.3g}: beacons "
                    f"{'collinear' if dim == 2 else 'coplanar'} or too close together")
    M = None
    if cond <= qr_condition:                                  # eq. 32 by Cholesky of the normal equations
        c, info = _dpotrf(AtA, lower=1)                        # LAPACK directly: ~2 us, scipy's wrappers ~20
        if info == 0:
            M = _dpotrs(c, A.T, lower=1)[0]
            method = "ols"
    if M is None:                                             # A = QR, R x = Q^T b by back substitution
        Qm, Rm = qr(A, mode="economic", check_finite=False)
        M = solve_triangular(Rm, Qm.T, check_finite=False)    # (A^T A)^-1 A^T without forming A^T A
        method = "qr"
    xrel = M @ b                                              # eq. 29: x - x_ref
    pos = B[ref].copy()
    pos[:dim] += xrel
    if dim == 2:
        pos[2] = z
    # First order: db_i = r_ref dr_ref - r_i dr_i (r at the fix, less noisy than measured)
    dB = pos - B
    d_fix = np.sqrt((dB * dB).sum(axis=1))
    Jb = np.zeros((k - 1, k))
    Jb[:, ref] = d_fix[ref]
    Jb[np.arange(k - 1), others] = -d_fix[others]
    return pos, M @ Jb, {"method": method, "cond": cond}


def _refine(B: np.ndarray, r: np.ndarray, pos: np.ndarray, dim: int, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton on the range equations (eq. 17) from ``pos``; returns the position and J (k, dim)."""
    pos = pos.copy()
    for _ in range(iterations + 1):
        d = pos - B
        rng = np.linalg.norm(d, axis=1)
        J = d[:, :dim] / np.maximum(rng, 1e-12)[:, None]     # unit lines of sight
        if _ == iterations:
            break
        c = cho_factor(J.T @ J, check_finite=False)
        pos[:dim] += cho_solve(c, J.T @ (r - rng), check_finite=False)
    return pos, J


def _fix(B: np.ndarray, r: np.ndarray, dim: int, z: float, z_sd: float, sigma: float, reference: str | int,
         qr_condition: float, degenerate_condition: float, refine: int) -> tuple[np.ndarray, np.ndarray, dict]:
    k = len(r)
    if k < dim + 1:
        raise NoFix("too_few_beacons", f"{k} range(s), a {dim}-D fix needs at least {dim + 1}")
    ref = int(np.argmin(r)) if reference == "nearest" else (0 if reference == "first" else int(reference))
    pos, G, info = _solve_linear(B, r, dim, z, ref, qr_condition, degenerate_condition)
    cov = np.zeros((3, 3))
    if refine:
        pos, J = _refine(B, r, pos, dim, refine)
        cov[:dim, :dim] = sigma**2 * cho_solve(cho_factor(J.T @ J, check_finite=False), np.eye(dim))
        info["method"] += "+gauss-newton"
    else:
        cov[:dim, :dim] = sigma**2 * (G @ G.T)               # cov of the OLS fix through the linear model
    if dim == 2:
        cov[2, 2] = z_sd**2
    info["reference"] = ref
    dB = pos - B
    info["residuals"] = r - np.sqrt((dB * dB).sum(axis=1))
    return pos, 0.5 * (cov + cov.T), info


def trilaterate(beacons: np.ndarray, ranges: np.ndarray, *, dim: int = 3, z: float = 0.0, z_sd: float = 0.0,
                sigma: float = 1.0, reference: str | int = "nearest", qr_condition: float = 1e6,
                degenerate_condition: float = 1e12, refine: int = 0, consistency_probability: float | None = None,
                consistency_sd: float | None = None, max_outliers: int = 1) -> tuple[np.ndarray, np.ndarray, dict]:
    """One position fix from ranges to known beacons (paper 000 eqs. 17-32).

    :param beacons: (k, 3) beacon positions (m, navigation frame; (k, 2) is padded with ``z``).
    :param ranges: (k,) measured ranges (m).
    :param dim: 3 (x, y, z unknown, k >= 4 non-coplanar) or 2 (the mine case: the receiver height is the
        known ``z``, k >= 3 non-collinear beacons).
    :param sigma: range noise sd (m); ``z_sd`` the sd attached to the known height in 2-D.
    :param reference: the reference beacon of eq. 25: ``nearest`` (shortest range: its noise enters every
        row of b scaled by its range), ``first`` (the paper's B1) or an index.
    :param qr_condition: above this cond(A^T A) the QR path (A = QR, R x = Q^T b) replaces the normal
        equations of eq. 32; above ``degenerate_condition`` there is no fix (``degenerate``).
    :param refine: Gauss-Newton iterations on the range equations after the OLS fix (0: the paper's OLS).
    :param consistency_probability: if set, chi-square test of the range residuals with ``k - dim`` degrees
        of freedom at sd ``consistency_sd`` (default ``sigma``); a failed test removes the beacon whose
        exclusion fits best (up to ``max_outliers``, needs k - dim >= 2) or gives no fix (``inconsistent``).
    :returns: ``(position (3,), covariance (3, 3), info)``. The covariance is first order: with the OLS
        fix ``x = M b(r)``, ``cov = sigma^2 (M J_b)(M J_b)^T`` where J_b = db/dr (b is eq. 25, so its errors
        are correlated through the reference range); after Gauss-Newton ``cov = sigma^2 (J^T J)^-1`` with
        J the unit line-of-sight rows. In 2-D the z row/column is ``z_sd^2`` on the diagonal only. ``info``:
        ``method`` (ols/qr[+gauss-newton]), ``cond`` (of A^T A), ``reference``, ``residuals`` (m),
        ``chi2``, ``dof``, ``used`` and ``rejected`` (indices into the input).
    :raises NoFix: with ``reason`` too_few_beacons, degenerate or inconsistent.
    """
    B = np.asarray(beacons, dtype=float)
    r = np.asarray(ranges, dtype=float)
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim}")
    if B.ndim != 2 or B.shape[1] not in (2, 3) or r.shape != (B.shape[0],):
        raise ValueError(f"expected beacons (k, 3) and ranges (k,), got {B.shape} and {r.shape}")
    if B.shape[1] == 2:
        B = np.column_stack([B, np.full(len(B), z)])
    if not (np.isfinite(B.sum()) and np.isfinite(r.sum())):     # one reduction each (a nan or inf propagates)
        raise ValueError("beacons and ranges must be finite")
    args = (dim, z, z_sd, sigma, reference, qr_condition, degenerate_condition, refine)
    idx = np.arange(len(r))
    pos, cov, info = _fix(B, r, *args)
    rejected: list[int] = []
    if consistency_probability is not None:
        sd = consistency_sd if consistency_sd is not None else sigma
        while True:
            dof = len(idx) - dim
            stat = float(np.sum(info["residuals"] ** 2) / sd**2)
            info.update(chi2=stat, dof=dof)
            if dof < 1 or stat <= chi2.ppf(consistency_probability, dof):
                break
            if dof < 2 or len(rejected) >= max_outliers:
                raise NoFix("inconsistent", f"range residuals chi2 = {stat:.1f} with {dof} dof "
                            f"(limit {chi2.ppf(consistency_probability, dof):.1f}, residuals "
                            f"{np.round(info['residuals'], 3).tolist()} m)")
            best = None
            for j in range(len(idx)):           # leave one out: keep the subset that fits best
                keep = np.r_[0:j, j + 1:len(idx)]
                sub = idx[keep]
                ref = reference if isinstance(reference, str) else int(np.flatnonzero(sub == reference)[0]) if reference in sub else 0
                try:
                    cand = _fix(B[idx[keep]], r[idx[keep]], *args[:4], ref, *args[5:])
                except NoFix:
                    continue
                s = float(np.sum(cand[2]["residuals"] ** 2))
                if best is None or s < best[0]:
                    best = (s, j, cand)
            if best is None:
                raise NoFix("inconsistent", "no consistent subset of the ranges")
            _, j, (pos, cov, info) = best
            rejected.append(int(idx[j]))
            idx = np.delete(idx, j)
    info["used"] = idx.tolist()
    info["rejected"] = rejected
    info.setdefault("chi2", float(np.sum(info["residuals"] ** 2) / sigma**2))
    info.setdefault("dof", len(idx) - dim)
    return pos, cov, info


_IU3 = np.triu_indices(3)


def pack_fix(position: np.ndarray, covariance: np.ndarray) -> tuple[float, ...]:
    """Message values of a fix: ``x y z cxx cxy cxz cyy cyz czz`` (m, m^2; the upper triangle)."""
    return tuple(np.concatenate([position, covariance[_IU3]]).tolist())


def unpack_fix(values: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`pack_fix`: position (3,) and covariance (3, 3)."""
    v = np.asarray(values, dtype=float)
    cov = np.zeros((3, 3))
    cov[np.triu_indices(3)] = v[3:9]
    cov = cov + np.triu(cov, 1).T
    return v[:3], cov


class OlsParams(Params):
    """YAML parameters of ``ols_trilateration`` (lengths in m, times in s)."""

    dim: Literal[2, 3] = Field(2, description="2: the mine case (z known), 3: x y z estimated")
    z: float = Field(0.0, description="receiver height (m, navigation frame) used in 2-D")
    z_sd: float = Field(0.1, ge=0, le=MAX_SD_M, description="sd (m) of the known height, attached to the 2-D fix")
    range_sd: float = Field(0.05, gt=0, le=MAX_SD_M, description="range noise sd (m): the fix covariance scales "
                            "with it")
    max_range: float | None = Field(None, gt=0, description="m: a longer range is malformed (not physical "
                                    "for the sensor; None: no limit)")
    window: float = Field(1.0, gt=0, description="a cycle holds ranges within this time of its first one")
    min_beacons: int | None = Field(None, ge=3, description="fewest beacons for a fix (default dim + 1)")
    beacons: list[str] | None = Field(None, description="beacons this receiver ranges (default: all); a cycle "
                                      "closes as soon as each has reported")
    reference: Literal["nearest", "first"] = "nearest"
    qr_condition: float = Field(1e6, gt=1, description="cond(A^T A) above which QR replaces eq. 32")
    degenerate_condition: float = Field(1e12, gt=1, description="cond(A^T A) above which there is no fix")
    refine_iterations: int = Field(0, ge=0, description="Gauss-Newton iterations after OLS (0: paper)")
    consistency_probability: float | None = Field(0.999, gt=0, lt=1, description="chi-square test of range "
                                                  "residuals (None: off, leave outliers to the filter's gate)")
    consistency_sd: float | None = Field(None, gt=0, le=MAX_SD_M, description="range sd (m) for that test (default "
                                         "range_sd; raise it to tolerate motion within a cycle)")
    max_outliers: int = Field(1, ge=0, description="ranges a cycle may drop to pass the test")
    age: bool = Field(False, description="with stamp close: refer the ranges to their mean time instead and "
                      "append that fix's age (s) at the closing time as a 10th value, for a measurement "
                      "model that bridges it with the state's velocity (position: p - v age)")
    stamp: Literal["mean", "last", "close"] = Field("mean", description="fix time: mean or last of the cycle's "
                                                    "ranges, or when the cycle closed (needs motion_compensation)")
    motion_compensation: bool = Field(False, description="refer every range of a cycle to the fix time with "
                                      "the velocity fitted to the recent fixes (not in the paper)")
    velocity_span: float = Field(1.3, gt=0, description="fixes within this many s give that velocity")
    max_speed: float = Field(3.0, gt=0, description="m/s; a faster fitted velocity is not used")
    accel_sd: float = Field(0.15, ge=0, le=MAX_SD_M, description="m/s^2: unmodelled acceleration, adds to the covariance of "
                            "a compensated fix (with the velocity's own uncertainty)")


class OlsTrilateration(Solver):
    """ABPS position fixes by OLS trilateration (paper 000 sec. IV, eqs. 17-32), as a sensor preprocessor.

    Input messages: ``beacon range`` (label, m); beacon positions from the config (``context.beacons``).
    A cycle gathers the latest range per beacon, starting at its first range; it closes when a beacon
    repeats, when a range comes ``window`` s after the first, or when every expected beacon has reported
    (then at once). A closed cycle with at least ``min_beacons`` ranges gives one fix (see
    :func:`trilaterate`: eq. 25 with the nearest beacon as reference, eq. 32 by Cholesky, QR when
    cond(A^T A) > ``qr_condition``), emitted as ``Message(t, sensor, (x, y, z, cxx, cxy, cxz, cyy, cyz,
    czz))``: position (m) and the upper triangle of its covariance (m^2), which the ``position`` model uses
    as R. ``t`` is set by ``stamp`` (below).

    Ranges of one cycle are taken at different times (paper 000: beacons fire in turn) while the vehicle
    moves (1 m/s over a 0.3 s cycle: 0.3 m). ``motion_compensation`` refers them all to the fix time
    t_fix: with v the least-squares velocity of the recent fixes (those within ``velocity_span`` s, each
    taken at the mean time of its ranges, so the velocity does not feed back on itself), the range taken
    at t_i is from the fix position displaced by v (t_i - t_fix), i.e. from the beacon shifted by
    -v (t_i - t_fix), and the same linear model applies. The covariance then gains tau^2 P_v plus an
    unmodelled-acceleration term (``accel_sd``), tau = t_fix - mean range time. ``stamp``: ``mean`` (the
    mean time of the ranges: best fix, 0.09 m RMSE on the ABPS recording), ``last`` (the last range),
    or ``close`` (needs compensation: the time of the message that closed the cycle, i.e. when the
    scheduler applies the fix, so an update is never applied later than its time stamp; 0.12 m RMSE,
    fix NEES ~2.3 for 2 dof on the recording). Without compensation the fix is an average over the cycle
    (0.145 m RMSE) and ``mean`` is its best time. ``age`` (with ``close``): the ranges are referred to
    their mean time t_m (where an error of the fitted velocity hardly matters) and the message, still
    sent at the closing time, carries the fix's age ``t_close - t_m`` as a 10th value; the ``position``
    model then predicts it as ``p - v age + C_b^n r`` with the filter's own velocity, instead of the fix
    extrapolating with the fitted one (whose error is shared by consecutive fixes).

    Outliers (1% in the ABPS recording, a longer reflected path): with redundancy (k > dim + 1) the range
    residuals are tested (chi-square, ``consistency_probability``) and the one beacon whose exclusion fits
    best is dropped; with k = dim + 1 the test can only refuse the fix. Smaller outliers are left to the
    filter's gate on the fix. No fix: ``counters`` counts the reason (``too_few_beacons``, ``degenerate``,
    ``inconsistent``) and ``events`` gets an Event ``no_fix``; a dropped range counts ``outliers_removed``
    and gives an Event ``rejected``.
    """

    name: ClassVar[str] = "ols_trilateration"
    Params: ClassVar[type[Params]] = OlsParams

    def __init__(self, params: OlsParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        p: OlsParams = self.params  # type: ignore[assignment]
        names = p.beacons if p.beacons is not None else list(self.context.beacons)
        unknown = [b for b in names if b not in self.context.beacons]
        if unknown:
            raise ConfigError(f"ols_trilateration: unknown beacon(s) {unknown}; the config defines "
                              f"{sorted(self.context.beacons)}")
        self.beacon_positions = {n: self._pad(self.context.beacons[n]) for n in names}
        self.min_beacons = p.min_beacons if p.min_beacons is not None else p.dim + 1
        if p.stamp == "close" and not p.motion_compensation:
            raise ConfigError("ols_trilateration: stamp: close needs motion_compensation: true (the ranges are "
                              "referred to the closing time with the fitted velocity)")
        if p.age and p.stamp != "close":
            raise ConfigError("ols_trilateration: age: true needs stamp: close (the age is the time from the "
                              "position the fix gives to the closing message)")
        if self.min_beacons < p.dim + 1:
            raise ConfigError(f"ols_trilateration: min_beacons {self.min_beacons} < {p.dim + 1} needed for a {p.dim}-D fix")
        if self.min_beacons > len(names):
            raise ConfigError(f"ols_trilateration: min_beacons {self.min_beacons} but only {len(names)} beacon(s) "
                              f"{names}: no cycle could ever give a fix")
        self.counters: dict[str, int] = {"cycles": 0, "fixes": 0, "qr": 0, "outliers_removed": 0,
                                         "unknown_beacon": 0, **{r: 0 for r in REASONS}}
        self.events: list[Event] = []
        self._cycle: dict[str, tuple[float, float]] = {}
        self._track: list[tuple[float, np.ndarray, np.ndarray]] = []   # recent fixes (t, position, cov)
        self._t_first = 0.0
        self._last: Message | None = None

    def _pad(self, b: Any) -> np.ndarray:
        b = np.asarray(b, dtype=float)
        return np.r_[b, self.params.z] if b.shape == (2,) else b  # type: ignore[attr-defined]

    def feed(self, message: Message) -> list[Message]:
        """Take one ``beacon range`` message (or several pairs); return the fix of a cycle that closed."""
        vals = message.values
        if len(vals) < 2 or len(vals) % 2:
            raise MalformedMessage(f"ols_trilateration expects 'beacon range' pairs, got {vals!r}")
        pairs = []
        for label, rng in zip(vals[0::2], vals[1::2]):
            if not isinstance(label, str) or label not in self.beacon_positions:
                self.counters["unknown_beacon"] += 1
                raise MalformedMessage(f"unknown beacon {label!r} (known: {', '.join(self.beacon_positions)})")
            try:
                rng = float(rng)
            except (TypeError, ValueError):
                raise MalformedMessage(f"range to {label} is not a number: {rng!r}") from None
            if not np.isfinite(rng) or rng < 0:
                raise MalformedMessage(f"range to {label} must be finite and >= 0, got {rng}")
            if rng > MAX_MAGNITUDE:
                raise MalformedMessage(f"range to {label} {rng} m beyond {MAX_MAGNITUDE:g} (its square overflows "
                                       "eq. 25)")
            if self.params.max_range is not None and rng > self.params.max_range:  # type: ignore[attr-defined]
                raise MalformedMessage(f"range to {label} {rng} m beyond max_range "
                                       f"{self.params.max_range} m")  # type: ignore[attr-defined]
            pairs.append((label, rng))
        if len(pairs) > 1 and len({label for label, _ in pairs}) != len(pairs):
            raise MalformedMessage(f"beacon named twice in one message {vals!r}")
        out: list[Message] = []
        for label, rng in pairs:
            if self._cycle and (label in self._cycle or message.t - self._t_first >= self.params.window):  # type: ignore[attr-defined]
                out += self._close(message.t)
            if not self._cycle:
                self._t_first = message.t
            self._cycle[label] = (message.t, rng)
            self._last = message
        if len(self._cycle) == len(self.beacon_positions):
            out += self._close(message.t)
        return out

    def flush(self) -> list[Message]:
        """The fix of the last, incomplete cycle (end of input)."""
        return self._close(None) if self._cycle else []

    def _close(self, t_close: float | None) -> list[Message]:
        """Solve the gathered cycle; ``t_close`` is the time of the message that closed it (None: flush)."""
        p: OlsParams = self.params  # type: ignore[assignment]
        names = list(self._cycle)
        times = np.array([self._cycle[n][0] for n in names])
        ranges = np.array([self._cycle[n][1] for n in names])
        B = np.array([self.beacon_positions[n] for n in names])
        self._cycle = {}
        self.counters["cycles"] += 1
        last = self._last
        assert last is not None
        t_end = float(times.max())
        t_ref = {"mean": float(times.mean()), "last": t_end,
                 "close": t_end if t_close is None else max(t_close, t_end)}[p.stamp]
        t_pos = float(times.mean()) if p.age else t_ref        # the time the fix's position is of
        v, Pv = np.zeros(3), None
        if p.motion_compensation:
            fit = self._velocity(float(times.mean()))
            if fit is not None:
                v, Pv = fit
                B = B - v * (times - t_pos)[:, None]             # ranges referred to t_pos
        try:
            if len(names) < self.min_beacons:
                raise NoFix("too_few_beacons", f"{len(names)} beacon(s) {names}, need {self.min_beacons}")
            with np.errstate(over="ignore", invalid="ignore"):    # overflowing ranges: caught just below
                pos, cov, info = trilaterate(
                    B, ranges, dim=p.dim, z=p.z, z_sd=p.z_sd, sigma=p.range_sd, reference=p.reference,
                    qr_condition=p.qr_condition, degenerate_condition=p.degenerate_condition,
                    refine=p.refine_iterations, consistency_probability=p.consistency_probability,
                    consistency_sd=p.consistency_sd, max_outliers=p.max_outliers)
            if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(cov))):
                raise NoFix("inconsistent", f"the fix is not finite (ranges {ranges.tolist()} m overflow eq. 25)")
        except NoFix as exc:
            self.counters[exc.reason] += 1
            self.events.append(Event(t_end, "no_fix", last.sensor, str(exc)))
            return []
        except (np.linalg.LinAlgError, ValueError) as exc:  # numbers no fix can come from (not finite)
            self.counters["inconsistent"] += 1
            self.events.append(Event(t_end, "no_fix", last.sensor, f"inconsistent: no fix from ranges "
                                     f"{ranges.tolist()} m: {exc}"))
            return []
        for j in info["rejected"]:
            self.counters["outliers_removed"] += 1
            self.events.append(Event(float(times[j]), "rejected", last.sensor,
                                     f"range to {names[j]} ({ranges[j]:.3f} m) inconsistent with the others; "
                                     f"fix from {len(info['used'])} beacons"))
        self.counters["fixes"] += 1
        self.counters["qr"] += info["method"].startswith("qr")
        used_t = times[info["used"]]
        t_bar = float(used_t.sum()) / len(used_t)
        if p.motion_compensation:
            # the velocity track takes the fix at the mean range time (not extrapolated: no feedback loop)
            self._track.append((t_bar, pos + v * (t_bar - t_pos), cov))
        if Pv is not None:                # velocity error and unmodelled acceleration over the mean offset
            tau = abs(t_bar - t_pos)
            acc = p.accel_sd * tau * (0.5 * tau + 0.5 * p.velocity_span)
            cov = cov + tau**2 * Pv + np.diag([acc**2, acc**2, acc**2 if p.dim == 3 else 0.0])
        if p.motion_compensation:
            t = t_ref
        else:
            used = times[info["used"]]
            t = float(used.mean()) if p.stamp == "mean" else float(used.max())
        values = pack_fix(pos, cov)
        if p.age:
            values += (t - t_pos,)
        return [Message(t, last.sensor, values, last.line)]

    def _velocity(self, t: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Least-squares velocity (3,) (m/s) of the fixes of the last ``velocity_span`` s and its covariance
        (3, 3) (the fixes taken as independent, with their mean covariance), or None."""
        p: OlsParams = self.params  # type: ignore[assignment]
        self._track = [f for f in self._track if t - f[0] <= p.velocity_span]
        if len(self._track) < 2:
            return None
        tt = np.array([f[0] for f in self._track])
        X = np.array([f[1] for f in self._track])
        tc = tt - tt.sum() / len(tt)
        if not tc.any():
            return None
        tc2 = float(tc @ tc)
        v = (tc @ X) / tc2                  # = tc @ (X - mean X) / tc2, since sum(tc) = 0
        Pv = sum(f[2] for f in self._track) / (len(self._track) * tc2)
        if p.dim == 2:
            v[2] = 0.0
            Pv[2, :] = Pv[:, 2] = 0.0
        return (v, Pv) if math.sqrt(float(v @ v)) <= p.max_speed else None
