"""Solver ``tdoa_geometric``: a 3-D position fix from one cycle of beacon arrival times (paper 003 sec. 4.1,
eqs. 1-8).

Beacons fire in turn, one every T seconds (eq. 1: ``t_i = (i - 1) T + t_g + d_i / c``, t_g unknown).
Differences to a reference beacon remove t_g: the measured distance differences are

.. math::
    \\Delta_{i} = d_i - d_1 = c\\,(t_i - t_1) - c\\,(n_i - n_1)\\,T

(n_i the firing count of beacon i's pulse). Starting from a guess r, the algorithm moves by
:math:`\\delta r` until the modelled differences match: the gradient of the field
:math:`d_{1i}(r) = d_i - d_1` is :math:`u_i - u_1` (eq. 3, u_i the unit vector from beacon i to the
robot), a first-order move changes :math:`d_{1i}` by :math:`\\delta r \\cdot \\nabla d_{1i}` (eq. 5), and in
the biorthogonal basis of the three gradients (eq. 4) the move is (eqs. 6-8)

.. math::
    \\delta r = \\frac{\\delta d_{12} (\\nabla d_{13} \\times \\nabla d_{14}) + \\delta d_{13}
    (\\nabla d_{14} \\times \\nabla d_{12}) + \\delta d_{14} (\\nabla d_{12} \\times \\nabla d_{13})}
    {\\nabla d_{12} \\cdot (\\nabla d_{13} \\times \\nabla d_{14})}

i.e. Newton's method on the three hyperboloids (3-4 iterations from a rough start). With more than four
beacons the move is the generalised least-squares one, ``dr = (G^T W G)^-1 G^T W dd`` with G the gradient
rows and W^-1 = I + 1 1^T the correlation of differences to one common reference (equal arrival noise);
for four beacons it is eq. 8 exactly. The fix covariance maps the arrival-time noise through the same
linearisation (eq. 8 "allows the error in position to be estimated"): ``(c sigma)^2 (G^T W G)^-1``.
"""
from __future__ import annotations

from typing import ClassVar, Literal, Sequence

import numpy as np
from pydantic import Field
from scipy.linalg import cho_factor, cho_solve

from fusion.api import BuildContext, ConfigError, Event, Fix, MalformedMessage, Message, Params, Solver

REASONS = ("too_few_beacons", "degenerate", "no_convergence")


class NoFix(ValueError):
    """No fix from these arrivals; ``reason`` is one of :data:`REASONS`."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


def distance_differences(arrivals: np.ndarray, firings: np.ndarray, period: float, c: float) -> np.ndarray:
    """Measured ``d_i - d_1`` (m), i = 2..k, from arrival times (k,) (s), firing counts (k,) and T (s)."""
    a = np.asarray(arrivals, float)
    n = np.asarray(firings, float)
    return c * (a[1:] - a[0]) - c * period * (n[1:] - n[0])


def _gradients(r: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distances d (k,) from beacons B (k, 3) to r, and the gradients u_i - u_1 (k-1, 3) (eq. 3)."""
    diff = r - B
    d = np.sqrt(np.einsum("kd,kd->k", diff, diff))
    u = diff / np.maximum(d, 1e-12)[:, None]
    return d, u[1:] - u[0]


def biorthogonal_step(G: np.ndarray, dd: np.ndarray, degenerate_tol: float = 1e-9) -> np.ndarray:
    """Eq. 8: the move dr (3,) with ``G dr = dd`` for the three gradient rows G (3, 3), written in the
    biorthogonal basis of the gradients. Raises NoFix('degenerate') when the triple product
    ``g1 . (g2 x g3)`` is below ``degenerate_tol`` times the product of the gradients' lengths."""
    g1, g2, g3 = G
    c23, c31, c12 = np.cross(g2, g3), np.cross(g3, g1), np.cross(g1, g2)
    triple = float(g1 @ c23)
    scale = float(np.linalg.norm(g1) * np.linalg.norm(g2) * np.linalg.norm(g3))
    if not np.isfinite(triple) or abs(triple) <= degenerate_tol * max(scale, 1e-300):
        raise NoFix("degenerate", f"gradients nearly coplanar (|g1.(g2 x g3)| = {abs(triple):.3g})")
    return (dd[0] * c23 + dd[1] * c31 + dd[2] * c12) / triple


def _gls_normal(G: np.ndarray) -> np.ndarray:
    """G^T W G with W = (I + 1 1^T)^-1 = I - 1 1^T / (1 + m) (Sherman-Morrison, m = rows of G)."""
    s = G.sum(axis=0)
    return G.T @ G - np.outer(s, s) / (1.0 + G.shape[0])


def _gls_step(G: np.ndarray, dd: np.ndarray, degenerate_condition: float) -> np.ndarray:
    N = _gls_normal(G)
    w = np.linalg.eigvalsh(N)
    if not np.all(np.isfinite(w)) or w[0] <= w[-1] / degenerate_condition:
        raise NoFix("degenerate", f"cond(G^T W G) = {w[-1] / max(w[0], 1e-300):.3g}")
    rhs = G.T @ dd - G.sum(axis=0) * dd.sum() / (1.0 + G.shape[0])
    return cho_solve(cho_factor(N, lower=True), rhs)


def tdoa_fix(beacons: np.ndarray, arrivals: np.ndarray, firings: np.ndarray, period: float, c: float,
             start: np.ndarray, sigma: float = 2e-4, max_iterations: int = 10, tolerance: float = 1e-9,
             degenerate_tol: float = 1e-9, max_step: float = 100.0) -> tuple[np.ndarray, np.ndarray, int]:
    """One geometric fix (paper 003 eqs. 1-8).

    :param beacons: (k, 3) positions (m), k >= 4, the first one the reference.
    :param arrivals: (k,) arrival times (s); ``firings``: (k,) firing counts of the pulses (integers).
    :param period: the inter-firing period T (s); ``c``: speed of sound (m/s).
    :param start: (3,) initial guess (m).
    :param sigma: arrival-time noise sd (s), for the covariance.
    :returns: position (3,) m, covariance (3, 3) m^2, iterations used.
    :raises NoFix: ``too_few_beacons``, ``degenerate`` (coplanar gradients, GLS condition above
        1/degenerate_tol), ``no_convergence`` (step above ``tolerance`` after ``max_iterations``, a step
        longer than ``max_step`` m, or a non-finite value).
    """
    B = np.asarray(beacons, float)
    k = B.shape[0]
    if k < 4:
        raise NoFix("too_few_beacons", f"{k} beacon(s), need 4 for a 3-D fix")
    meas = distance_differences(arrivals, firings, period, c)
    if not np.all(np.isfinite(meas)):
        raise NoFix("no_convergence", "non-finite arrival times")
    r = np.asarray(start, float).copy()
    for it in range(1, max_iterations + 1):
        d, G = _gradients(r, B)
        dd = meas - (d[1:] - d[0])                      # errors in the differences of distance
        step = (biorthogonal_step(G, dd, degenerate_tol) if k == 4
                else _gls_step(G, dd, 1.0 / degenerate_tol))
        size = float(np.sqrt(step @ step))
        if not np.isfinite(size) or size > max_step:
            raise NoFix("no_convergence", f"iteration {it}: step of {size:.3g} m")
        r = r + step
        if size <= tolerance:
            break
    else:
        raise NoFix("no_convergence", f"step still {size:.3g} m after {max_iterations} iterations")
    _, G = _gradients(r, B)
    N = _gls_normal(G)
    try:
        cov = (c * sigma) ** 2 * cho_solve(cho_factor(N, lower=True), np.eye(3))
    except np.linalg.LinAlgError:
        raise NoFix("degenerate", "singular geometry at the fix") from None
    return r, 0.5 * (cov + cov.T), it


def stationary_bound(beacons: np.ndarray, position: np.ndarray, firings: np.ndarray, c: float,
                     sigma: float) -> np.ndarray:
    """Cramer-Rao bound (5, 5) of ``[x y z T t0]`` (m, s, s) from arrival times of a stationary robot.

    Arrival j comes from beacon ``beacons[j]`` (k, 3) (m) fired ``firings[j]`` periods after t0
    (eq. 1 / eq. 11: ``t_j = t0 + n_j T + |p - b_j| / c``) with white noise of sd ``sigma`` (s). The
    information is ``J^T J / sigma^2`` with rows ``J_j = [(p - b_j)^T / (c |p - b_j|), n_j, 1]``; the bound
    is its inverse. It is the smallest covariance any unbiased estimator of a constant position and clock
    reaches from these arrivals, and the covariance a stationary filter (no position random walk, a
    constant period) reports after them: Table II's "standard deviation from filter" is this number, not
    a property of the estimator. Raises ``numpy.linalg.LinAlgError`` when the arrivals cannot fix the state
    (fewer than 4 beacons, one firing, ...)."""
    B = np.atleast_2d(np.asarray(beacons, float))
    d = np.asarray(position, float) - B
    u = d / np.linalg.norm(d, axis=1, keepdims=True)
    J = np.column_stack([u / c, np.asarray(firings, float), np.ones(len(B))])
    info = J.T @ J / sigma ** 2
    w = np.linalg.eigvalsh(info)
    if not np.all(np.isfinite(w)) or w[0] <= 1e-12 * w[-1]:
        raise np.linalg.LinAlgError("stationary_bound: the arrivals do not determine [x y z T t0]")
    cov = cho_solve(cho_factor(info, lower=True), np.eye(5))
    return 0.5 * (cov + cov.T)


class AgreeingFixes:
    """Consecutive fixes that agree: ``add(position, cov)`` returns the mean of the last ``n`` fixes (and its
    covariance, the mean covariance / n) once each agrees with the one before, else None.

    Two fixes agree when ``d^T (2 C_s)^-1 d <= chi2.ppf(probability, 3)``, d their difference and C_s the
    covariance of the better-determined of the two (the smaller determinant). With four beacons an echo
    moves a fix by tens of cm and nothing in the cycle shows it; three fixes in a row that agree are very
    unlikely to all carry one (an initialiser must not start a filter, confidently, in the wrong place).
    Why not ``C_a + C_b``: an echo can throw a fix far out, where the hyperboloids meet at a grazing angle
    and the fix's own covariance is metres wide; with ``C_a + C_b`` that fix "agrees" with every good one
    and, averaged in, puts the filter metres off with a metres-wide covariance, through which the gate then
    lets echoes in (seen at the far static position of paper 003's Table I: a start 7.9 m off). Two fixes
    of one position have about the same covariance, so ``2 C_s`` keeps the test's level when they do agree.
    (The mean stays the plain one: weighting by each fix's own covariance, which depends on where the fix
    fell, pulls the mean towards the beacons.)"""

    def __init__(self, n: int, probability: float = 0.99):
        from fusion.chisquare import chi2

        self.n = n
        self.threshold = float(chi2.ppf(probability, 3))
        self.run: list[tuple[np.ndarray, np.ndarray]] = []
        self.data: list = []        # what the caller gave with each fix of the run (add's ``data``)

    def agree(self, pos_a: np.ndarray, cov_a: np.ndarray, pos_b: np.ndarray, cov_b: np.ndarray) -> bool:
        """The agreement test of two fixes (m, m^2)."""
        d = np.asarray(pos_a, float) - np.asarray(pos_b, float)
        small = cov_a if np.linalg.det(cov_a) <= np.linalg.det(cov_b) else cov_b
        try:
            return float(d @ cho_solve(cho_factor(2.0 * small, lower=True), d)) <= self.threshold
        except np.linalg.LinAlgError:
            return False

    def add(self, pos: np.ndarray, cov: np.ndarray, data=None) -> tuple[np.ndarray, np.ndarray] | None:
        """Add a fix (and anything the caller keeps with it, ``data``); the mean once ``n`` agree in a row
        (then :meth:`agreeing` gives their ``data``)."""
        if self.run and not self.agree(pos, cov, *self.run[-1]):
            self.reset()
        self.run.append((pos, cov))
        self.data.append(data)
        if len(self.run) < self.n:
            return None
        run = self.run[-self.n:]
        return (np.mean([p for p, _ in run], axis=0), np.mean([c for _, c in run], axis=0) / self.n)

    def agreeing(self) -> list:
        """The ``data`` of the last ``n`` fixes (those of the mean ``add`` returned)."""
        return self.data[-self.n:]

    def reset(self) -> None:
        self.run = []
        self.data = []


class TdoaParams(Params):
    """YAML parameters of ``tdoa_geometric`` (m, s)."""

    period_s: float = Field(0.225, gt=0, description="inter-firing period T (s), known (paper 003: 225 ms)")
    speed_of_sound: float = Field(340.0, gt=0, description="c (m/s)")
    arrival_sd: float = Field(2.0e-4, gt=0, description="arrival-time noise sd (s), for the fix covariance")
    beacons: list[str] | None = Field(None, description="beacons in firing order (default: all config beacons)")
    start: tuple[float, float, float] | None = Field(None, description="initial guess (m; default: the "
                                                     "beacons' centroid)")
    warm_start: bool = Field(True, description="start each fix from the previous one (the start above "
                             "after a failure)")
    max_iterations: int = Field(10, ge=1, description="iterations at most (the paper needs 3-4)")
    tolerance: float = Field(1e-9, gt=0, description="converged when the step is below this (m)")
    degenerate_tol: float = Field(1e-9, gt=0, description="relative triple product (or 1/condition) below "
                                  "which the geometry is degenerate")
    output: Literal["fix", "initialise"] = Field("fix", description="fix: one position fix (a fusion.api.Fix: "
                                                 "x y z and its covariance) per cycle; initialise: one "
                                                 "initial state fix (position and firing time), then every "
                                                 "arrival passed through unchanged (the arrival_time model "
                                                 "observes the fix as the filter's first update)")
    initialise_agree: int = Field(3, ge=1, description="initialise: the fix is the mean of this many "
                                  "consecutive fixes that agree (chi-square, 99 %), so echoes cannot "
                                  "place the filter")
    initialise_stationary: bool = Field(False, description="initialise, for a robot known to stand still "
                                        "(paper 003 Tables I-II): the fix is the batch fix of every arrival "
                                        "so far that fits the agreeing fixes' position (stationary_fix), not "
                                        "of those three cycles only")


class TdoaGeometric(Solver):
    """Geometric TDOA position fixes (paper 003 sec. 4.1, eqs. 1-8) as a sensor preprocessor.

    Input: ``beacon arrival [receiver]`` messages (arrival time in s). A cycle gathers one arrival per
    beacon; it closes when every beacon of ``beacons`` has reported (the fix is stamped at the last
    arrival), when a beacon repeats or when an arrival comes a full cycle (k T) after the first. The firing
    counts come from the arrival times, ``n_i - n_1 = round((t_i - t_1) / T)``, so a missed pulse only
    removes its beacon. A cycle with four or more beacons gives a fix by :func:`tdoa_fix` from the previous
    fix (``warm_start``) or ``start``: a :class:`fusion.api.Fix` of the position (m) and its covariance
    (m^2), stamped at the last arrival, for the ``position`` model (its covariance as R). No fix: ``counters`` counts the reason
    (``too_few_beacons``, ``degenerate``, ``no_convergence``) and ``events`` gets a ``no_fix`` Event.
    With four beacons there is no redundancy: an echo shifts the fix and cannot be detected here (paper).
    ``output: initialise`` emits one initial state fix (position, the time of the last firing and the firing
    period, their covariance: :mod:`fusion_plugins.solvers.initial_fix`) once the first ``initialise_agree``
    consecutive fixes agree with each other (:class:`AgreeingFixes`): with two or more, [p, t0, T] from their
    arrivals (:func:`agreed_period`; ``period_s`` is the nominal period, which counts the firings), with one
    their mean at ``period_s``; then it passes every arrival through.
    """

    name: ClassVar[str] = "tdoa_geometric"
    Params: ClassVar[type[Params]] = TdoaParams

    def __init__(self, params: TdoaParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        p: TdoaParams = self.params  # type: ignore[assignment]
        names = p.beacons if p.beacons is not None else list(self.context.beacons)
        unknown = [b for b in names if b not in self.context.beacons]
        if unknown:
            raise ConfigError(f"tdoa_geometric: unknown beacon(s) {unknown}; the config defines "
                              f"{sorted(self.context.beacons)}")
        if len(names) < 4:
            raise ConfigError(f"tdoa_geometric: needs at least 4 beacons for a 3-D fix, got {names}")
        self.beacon_positions = {n: np.asarray(self.context.beacons[n], float) for n in names}
        if any(b.shape != (3,) for b in self.beacon_positions.values()):
            raise ConfigError("tdoa_geometric: beacons need 3 coordinates (x y z, m)")
        self.start = (np.asarray(p.start, float) if p.start is not None
                      else np.mean(list(self.beacon_positions.values()), axis=0))
        self.counters: dict[str, int] = {"cycles": 0, "fixes": 0, "iterations": 0, **{r: 0 for r in REASONS}}
        self.events: list[Event] = []
        self._cycle: dict[str, tuple[float, Message]] = {}
        self._previous: np.ndarray | None = None
        self._initialised = False
        self._agree = AgreeingFixes(p.initialise_agree)
        self._history: list[tuple[str, float]] = []     # initialise_stationary: every arrival until the fix

    def feed(self, message: Message) -> list[Message | Fix]:
        """Take one ``beacon arrival [receiver]`` message; return the fix of a cycle that closed (or, after
        the first fix with ``output: initialise``, the message itself)."""
        p: TdoaParams = self.params  # type: ignore[assignment]
        if p.output == "initialise" and self._initialised:
            return [message]
        try:
            label, arrival = parse_arrival(message, self.beacon_positions)
        except MalformedMessage as exc:
            return self._malformed(message, exc)
        out: list[Message | Fix] = []
        if self._cycle:
            t_first = min(a for a, _ in self._cycle.values())
            if label in self._cycle or arrival - t_first >= len(self.beacon_positions) * p.period_s:
                out += self._close()
        self._cycle[label] = (arrival, message)
        if p.initialise_stationary and len(self._history) < 100_000:
            self._history.append((label, arrival))
        if len(self._cycle) == len(self.beacon_positions):
            out += self._close()
        return out

    def _malformed(self, message: Message, exc: Exception) -> list[Message | Fix]:
        """A bad message is counted (``counters['malformed']``) and reported as an event, not raised: the
        run goes on (a raise from a preprocessor would stop it)."""
        self.counters["malformed"] = self.counters.get("malformed", 0) + 1
        self.events.append(Event(message.t, "malformed", message.sensor, f"line {message.line}: {exc}"))
        return []

    def flush(self) -> list[Message | Fix]:
        """The last, incomplete cycle (end of input): a fix only if it has enough beacons."""
        return self._close() if self._cycle and not self._initialised else []

    def _close(self) -> list[Message | Fix]:
        p: TdoaParams = self.params  # type: ignore[assignment]
        cycle, self._cycle = self._cycle, {}
        names = sorted(cycle, key=lambda n: cycle[n][0])
        a = np.array([cycle[n][0] for n in names])
        last = cycle[names[-1]][1]
        self.counters["cycles"] += 1
        firings = np.rint((a - a[0]) / p.period_s)
        start = self._previous if (p.warm_start and self._previous is not None) else self.start
        try:
            pos, cov, it = tdoa_fix(np.array([self.beacon_positions[n] for n in names]), a, firings,
                                    p.period_s, p.speed_of_sound, start, p.arrival_sd, p.max_iterations,
                                    p.tolerance, p.degenerate_tol)
        except NoFix as exc:
            self.counters[exc.reason] += 1
            self._previous = None
            self._agree.reset()
            self.events.append(Event(float(a[-1]), "no_fix", last.sensor, f"tdoa_geometric: {exc}"))
            return []
        self.counters["fixes"] += 1
        self.counters["iterations"] += it
        self._previous = pos
        if p.output == "initialise":
            agreed = self._agree.add(pos, cov, (names, a))
            if agreed is None:
                return []
            from .initial_fix import initial_fix
            self._initialised = True
            pos, cov = agreed
            where = {"sensor": last.sensor, "line": last.line, "used": tuple(names)}
            period = agreed_period(self._agree.agreeing(), self.beacon_positions, p.period_s, p.speed_of_sound,
                                   p.arrival_sd, self.start)
            if p.initialise_stationary:
                try:
                    return [self._stationary(pos, cov, float(a[-1]), where, period)]
                except np.linalg.LinAlgError:     # cannot happen with the agreeing cycles kept; be safe
                    self._history = []
            if period is not None:
                return [period_initial_fix(period, float(a[-1]), **where)]
            return [initial_fix(pos, cov, self.beacon_positions[names[-1]], float(a[-1]), p.speed_of_sound,
                                p.arrival_sd, **where)]
        return [Fix(float(a[-1]), pos, cov, used=tuple(names), sensor=last.sensor, line=last.line)]

    def _stationary(self, start: np.ndarray, start_cov: np.ndarray, t: float, where: dict,
                    period: tuple | None = None) -> Fix:
        """The initial fix (fusion_plugins.solvers.initial_fix), stamped at ``t``, of every arrival so far, from
        the agreeing position; with ``period`` (:func:`agreed_period`) the arrivals are counted with its
        estimated T and fix [p, t0, T] together (stationary_period_fix)."""
        from .initial_fix import period_state_fix, state_fix
        from .stationary_fix import stationary_fix, stationary_period_fix

        p: TdoaParams = self.params  # type: ignore[assignment]
        B = np.array([self.beacon_positions[b] for b, _ in self._history])
        a = np.array([t for _, t in self._history])
        self._history = []
        if period is not None:
            # the standing robot's consistent arrivals fix the period too: [p, t0, T], counted with the
            # agreeing cycles' estimate of T
            pos, t0, T, X, _ = stationary_period_fix(B, a, period[2], p.speed_of_sound, p.arrival_sd, start,
                                                     start_cov)
            n_last = float(np.rint((a[-1] - a[0]) / period[2]))        # t: the latest firing, t0 + n T
            return period_state_fix(t, pos, t0, T, n_last, X, **where)
        pos, t0, C, _ = stationary_fix(B, a, p.period_s, p.speed_of_sound, p.arrival_sd, start, start_cov)
        n_last = float(np.rint((a[-1] - a[0]) / p.period_s))
        return state_fix(t, pos, C[:3, :3], t0 + n_last * p.period_s, C[:3, 3], float(C[3, 3]), **where)


def agreed_period(cycles: list, beacons: dict, period: float, c: float, sigma: float, start: np.ndarray
                  ) -> tuple[np.ndarray, float, float, np.ndarray, float, np.ndarray] | None:
    """The fix of ``[p, t0, T]`` from the arrivals of the agreeing cycles (``cycles``: (names, arrival times
    (s)) each, in time order), or None when they cannot determine the period (fewer than two cycles).

    1. T by least squares of the arrival times against the firing numbers (counted with the nominal
       ``period``, s), one intercept per beacon (its time of flight): the position does not enter, so the
       cycles' fixes, which a period 0.5 % off throws 1-2 m out, do not either.
    2. Each cycle's fix (:func:`tdoa_fix`) again with that T, from ``start`` (m: the solver's cold start,
       not the fixes made with the nominal period, which can lie outside the basin); their mean starts
    3. :func:`fusion_plugins.solvers.stationary_fix.period_fix` on every arrival: ``[p, t0, T]`` and their
       covariance.

    :returns: ``(p, t0, T, cov (5, 5), latest firing count, last beacon (3,))``.
    """
    from .stationary_fix import period_fix

    if len(cycles) < 2:
        return None
    names = [n for ns, _ in cycles for n in ns]
    a = np.concatenate([np.asarray(t, float) for _, t in cycles])
    n = np.rint((a - a[0]) / period)
    num = den = 0.0
    for b in set(names):
        m = np.array([x == b for x in names])
        if m.sum() > 1:
            dn, da = n[m] - n[m].mean(), a[m] - a[m].mean()
            num, den = num + float(dn @ da), den + float(dn @ dn)
    if den == 0.0:
        return None
    T0 = num / den
    if not (np.isfinite(T0) and abs(T0 - period) < 0.05 * period):    # 5 % off: not this schedule
        return None
    fixes = []
    for ns, t in cycles:
        t = np.asarray(t, float)
        try:
            fixes.append(tdoa_fix(np.array([beacons[x] for x in ns]), t, np.rint((t - t[0]) / T0), T0, c,
                                  start, sigma)[0])
        except NoFix:
            pass
    B = np.array([beacons[x] for x in names])
    try:
        pos, t0, T, cov = period_fix(B, a, T0, c, sigma, np.mean(fixes, axis=0) if fixes else start)
    except np.linalg.LinAlgError:
        return None
    if not (np.all(np.isfinite(pos)) and abs(T - period) < 0.05 * period):
        return None
    return pos, t0, T, cov, float(np.rint((a[-1] - a[0]) / T0)), B[-1]


def period_initial_fix(period: tuple, t: float, q: np.ndarray | None = None, q_sd: float | None = None,
                       **where) -> Fix:
    """The initial state fix ``[p, t, T]`` stamped at ``t`` (s, the last arrival) from :func:`agreed_period`'s
    result: the latest firing ``t0 + n_last T`` (s)."""
    from .initial_fix import period_state_fix

    pos, t0, T, cov, n_last, _ = period
    return period_state_fix(t, pos, t0, T, n_last, cov, q, q_sd, **where)


def parse_arrival(message: Message, known: Sequence[str]) -> tuple[str, float]:
    """(beacon, arrival time s) of a ``beacon arrival [receiver]`` message; MalformedMessage when bad."""
    vals = message.values
    if len(vals) not in (2, 3):
        raise MalformedMessage(f"expected 'beacon arrival [receiver]', got {len(vals)} values")
    label = vals[0]
    if not isinstance(label, str) or label not in known:
        raise MalformedMessage(f"unknown beacon {label!r} (known: {', '.join(known)})")
    try:
        arrival = float(vals[1])
    except (TypeError, ValueError):
        raise MalformedMessage(f"arrival time of {label} is not a number: {vals[1]!r}") from None
    if not np.isfinite(arrival):
        raise MalformedMessage(f"arrival time of {label} must be finite, got {arrival}")
    return label, arrival
