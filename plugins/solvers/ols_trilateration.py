"""Solver ``ols_trilateration``: a position fix from one firing cycle of beacon ranges (paper 000 sec. IV,
eqs. 17-32).

The pure function :func:`trilaterate` (plugins/solvers/trilateration.py, re-exported here) does one fix
(used by tests and initialisers); the component
:class:`OlsTrilateration` is the sensor preprocessor that groups ``beacon range`` messages into firing
cycles (plugins/solvers/firing_schedule.py), refers each cycle's ranges to one time with the filter's
velocity (fusion.api.ReadsBelief) and emits one fix message with an honest covariance
(plugins/solvers/range_fix.py).
"""
from __future__ import annotations

import math
from typing import Any, Callable, ClassVar, Literal

import numpy as np
from pydantic import Field

from fusion.api import (MAX_MAGNITUDE, Belief, BuildContext, ConfigError, Event, Fix, MalformedMessage, Message,
                        Params, Solver)
from fusion_plugins.solvers.firing_schedule import FiringSchedule
from fusion_plugins.solvers.range_fix import NoFix
from fusion_plugins.solvers.trilateration import pack_fix, trilaterate, unpack_fix  # noqa: F401 (re-exported)

REASONS = ("too_few_beacons", "degenerate", "inconsistent", "ambiguous")
REACQUIRE_AFTER = 3  # compensated cycles refused in a row after which a cycle is solved without the belief
MAX_SD_M = 1e6   # m (m/s^2 for accel_sd): its square must stay finite through the fix covariance; no sensor is worse
_LOWER3 = np.tril_indices(3, -1)

__all__ = ["NoFix", "trilaterate", "pack_fix", "unpack_fix", "OlsParams", "OlsTrilateration"]


def _rotate(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """C_b^n(q) r for one quaternion (scalar first, any norm) and one body vector: r + 2 w (u x r) + 2 u x (u x r)
    with q normalised, in floats (fusion.quaternion.rotate is for batches; this runs once per cycle)."""
    w, a, b, c = q.tolist()
    n = math.sqrt(w * w + a * a + b * b + c * c)
    w, a, b, c = w / n, a / n, b / n, c / n
    x, y, z = r.tolist()
    tx, ty, tz = 2.0 * (b * z - c * y), 2.0 * (c * x - a * z), 2.0 * (a * y - b * x)     # t = 2 u x r
    return np.array([x + w * tx + (b * tz - c * ty), y + w * ty + (c * tx - a * tz), z + w * tz + (a * ty - b * tx)])


class OlsParams(Params):
    """YAML parameters of ``ols_trilateration`` (lengths in m, times in s)."""

    dim: Literal[2, 3] = Field(2, description="2: the mine case (height z known to z_sd), 3: x y z from the ranges")
    z: float = Field(0.0, description="receiver height (m, navigation frame) assumed in 2-D")
    z_sd: float = Field(0.1, ge=0, le=MAX_SD_M, description="sd (m) of that height: a range error shared by a cycle in the fix "
                        "covariance (refine > 0; the prior with solve_height) and the sd of the fix's z")
    range_sd: float = Field(0.05, gt=0, le=MAX_SD_M, description="range noise sd (m)")
    max_range: float | None = Field(None, gt=0, description="m: a longer range is malformed (not physical "
                                    "for the sensor; None: no limit)")
    firing_period: float | None = Field(None, gt=0, description="s: the beacons' firing period, which decides the "
                                        "cycles (None: learnt from the stream)")
    speed_of_sound: float | None = Field(None, gt=0, description="m/s: ultrasonic time of flight; the emission "
                                         "time t - r / c places a range in its firing slot (None: the arrival time)")
    learn_s: float = Field(2.0, gt=0, description="s of ranges from which the period (if not given) and the "
                           "slot phases are learnt (the ranges are held meanwhile)")
    min_beacons: int | None = Field(None, ge=3, description="fewest beacons for a fix (default dim + 1)")
    beacons: list[str] | None = Field(None, description="beacons this receiver ranges (default: all); a cycle "
                                      "closes as soon as each has reported")
    close_at_last_slot: bool = Field(True, description="close a cycle as soon as the latest slot of the beacons "
                                     "heard in the last cycles has reported (plugins/solvers/firing_schedule.py), "
                                     "not at a range of the next cycle: the fix is stamped no later than its data")
    reference: Literal["nearest", "first"] = "nearest"
    qr_condition: float = Field(1e6, gt=1, description="cond(A^T A) above which QR replaces eq. 32")
    degenerate_condition: float = Field(1e12, gt=1, description="cond(A^T A) above which there is no fix")
    refine_iterations: int = Field(0, ge=0, description="Gauss-Newton iterations after OLS (0: the paper's OLS)")
    consistency_probability: float | None = Field(0.999, gt=0, lt=1, description="chi-square test of the "
                                                  "whitened range residuals (None: off, outliers left to the gate)")
    max_outliers: int = Field(2, ge=0, description="ranges a cycle may drop to pass the test (consensus)")
    motion_compensation: bool = Field(False, description="refer every range of a cycle to the fix time with the "
                                      "filter's predicted velocity (fusion.api.ReadsBelief; not in the paper)")
    velocity_sd: float = Field(0.05, ge=0, description="m/s: receiver velocity the state's v does not carry (a "
                               "lever arm turning), added to the filter's velocity uncertainty")
    accel_sd: float = Field(0.5, ge=0, le=MAX_SD_M, description="m/s^2: acceleration within a cycle (unmodelled)")
    lever_arm: tuple[float, float, float] | None = Field(None, description="receiver in the body frame (m, FRD), "
                                                         "as the position model's: with compensation the "
                                                         "fix starts from the belief's receiver position")
    input_acceleration: bool = Field(False, description="with compensation: refer the ranges with the velocity at "
                                     "the cycle's mean time, the belief's minus the IMU's acceleration over the age "
                                     "(C_b^n (f - b_a) + g_n from the latest input sample: fusion.api.UsesInput, "
                                     "the run then integrates the inputs up to every range; state blocks q, ba), "
                                     "plus a dt^2 / 2; pairs with the position model's bridge: imu")
    gravity: float = Field(9.80665, gt=0, description="m/s^2, down: g_n of input_acceleration")
    prior_speed_sd: float = Field(1.0, gt=0, description="m/s: velocity sd while the filter has no belief yet "
                                  "(velocity 0 assumed)")
    solve_height: bool = Field(False, description="2-D with refine: estimate z with the prior N(z, z_sd^2) "
                               "(for beacons well above the receiver) instead of taking it as known to z_sd")
    inflate_misfit: bool = Field(True, description="scale the fix covariance by max(1, chi2 / dof)")


class OlsTrilateration(Solver):
    """ABPS position fixes by OLS trilateration (paper 000 sec. IV, eqs. 17-32), as a sensor preprocessor.

    Input messages: ``beacon range`` (label, m); beacon positions from the config (``context.beacons``).

    **Cycles from the firing schedule** (plugins/solvers/firing_schedule.py): the beacons fire in turn
    every ``firing_period`` (given, or learnt from the first ``learn_s`` of the stream); the emission time of
    a range (arrival time minus r / ``speed_of_sound``) puts it in its firing cycle. A repeat of a beacon
    never merges two cycles; a cycle that would span more than its period, or hold a beacon twice, is
    split. A second report of one pulse (emissions of one beacon closer than half a slot spacing: a repeated
    or retransmitted line, an echo stamped with the direct pulse's time) is no period while learning and
    in a cycle the shorter range is kept: counted ``duplicate_pulses``, an Event ``rejected``. A period that
    cannot be learnt gives an Event ``warning`` saying so. A cycle closes when the latest slot of the
    beacons heard in the last cycles has reported (``close_at_last_slot``: a beacon back in reach in a later
    slot then loses that range, counted ``late_ranges``, an Event ``rejected``), else when a range of a later
    cycle arrives, when every configured beacon has reported, or at the end of the input (flush).

    **Motion compensation** (``motion_compensation``): the fix is of the receiver at the mean time t_m of
    the cycle's ranges; the filter's belief predicted to t_m (fusion.api.ReadsBelief) gives the velocity v
    and its covariance P_v, and the range taken at t_i is from the beacon shifted by ``-v (t_i - t_m)``.
    The uncertainty of that shift (P_v plus ``velocity_sd``^2, and ``accel_sd``) is part of the fix
    covariance. Every cycle is compensated, also right after a failed fix. The fix is stamped at the
    belief's time; when that is later than t_m (inputs past t_m already integrated), the message carries
    the age ``t - t_m`` as a 10th value and the ``position`` model bridges it with the state's velocity
    (first order, or with the IMU: its ``bridge``). The velocity is then the belief's, ``age`` after t_m:
    its difference from the velocity at t_m (``accel_sd`` x age) is part of the compensation's uncertainty.
    The cycle closes at its last heard slot (``close_at_last_slot``), so the belief is no later than the
    cycle's last range and the age at most about half the cycle's span.
    Before the filter has a belief, v = 0 with sd ``prior_speed_sd``. Without compensation the fix is
    stamped at t_m, and its covariance takes the unknown motion over the cycle (velocity sd
    ``prior_speed_sd``) as correlated range errors.

    **The fix** (:func:`trilaterate`): eq. 25 with the nearest beacon as reference, eq. 32 by Cholesky,
    QR when cond(A^T A) > ``qr_condition``; then up to ``refine_iterations`` Gauss-Newton steps on the
    whitened range equations, from the belief's receiver position (``lever_arm``) when compensating, else
    from the OLS fix. Covariance: range noise and geometry, the compensation uncertainty, the assumed
    height (2-D) and the residual misfit (``inflate_misfit``), plugins/solvers/range_fix.py. Emitted as a
    ``fusion.api.Fix``: position (3,) (m, NED), its covariance (3, 3) (m^2), which the ``position`` model
    uses as R, the age (s) and the beacons used. (A recording may carry the same fix as a line of 9 or 10
    numbers, :func:`pack_fix`; the position model reads both.)

    **Outliers** (1% in the ABPS recording, a longer reflected path): consensus over subsets scored by
    the chi-square of the residuals; no fix when no subset is consistent or two disagree. No fix:
    ``counters`` counts the reason (``too_few_beacons``, ``degenerate``, ``inconsistent``, ``ambiguous``)
    and ``events`` gets an Event ``no_fix``; a dropped range counts ``outliers_removed`` and gives an
    Event ``rejected``.
    """

    name: ClassVar[str] = "ols_trilateration"
    fields = ("beacon", "range")
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
        if self.min_beacons > len(self.beacon_positions):
            raise ConfigError(f"ols_trilateration: min_beacons {self.min_beacons} but only "
                              f"{len(self.beacon_positions)} beacon(s): no cycle could ever give a fix")
        if self.min_beacons < p.dim + 1:
            raise ConfigError(f"ols_trilateration: min_beacons {self.min_beacons} < {p.dim + 1} needed for a {p.dim}-D fix")
        self._v: slice | None = None
        self._refused = 0   # compensated cycles refused as inconsistent in a row (REACQUIRE_AFTER)
        self._p: slice | None = None
        self._q: slice | None = None
        self._arm = np.asarray(p.lever_arm, dtype=float) if p.lever_arm is not None else np.zeros(3)
        if p.motion_compensation:
            layout = self.context.layout
            if layout is not None:
                if "v" not in layout:
                    raise ConfigError("ols_trilateration: motion_compensation needs a state with a velocity "
                                      f"block 'v' (this state has {[b.name for b in layout.blocks]})")
                self._v = layout["v"]
                self._p = layout["p"] if "p" in layout else None
                qs = [b.name for b in layout.blocks if b.kind == "quaternion"]
                self._q = layout[qs[0]] if qs and np.any(self._arm) else None
                if p.input_acceleration:
                    if not qs:
                        raise ConfigError("ols_trilateration: input_acceleration needs a state with an attitude "
                                          "quaternion (an ins process)")
                    self._qa = layout[qs[0]]
                    self._ba = layout["ba"] if "ba" in layout else None
                    # fusion.api.UsesInput only in this mode (the run integrates the inputs up to every range)
                    self.take_input = self._take_input
        self._u: np.ndarray | None = None     # the latest input sample (input_acceleration)
        self.counters: dict[str, int] = {"cycles": 0, "fixes": 0, "qr": 0, "outliers_removed": 0,
                                         "unknown_beacon": 0, "split_cycles": 0, "compensated": 0,
                                         **{r: 0 for r in REASONS}}
        self.events: list[Event] = []
        self.schedule = FiringSchedule(p.firing_period, p.speed_of_sound, p.learn_s, len(self.beacon_positions),
                                       close_at_last_slot=p.close_at_last_slot)
        self._belief_at: Callable[[float], Belief | None] | None = None
        self._sensor = self.context.sensor or "abps"
        self._line: int | None = None

    def _pad(self, b: Any) -> np.ndarray:
        b = np.asarray(b, dtype=float)
        return np.r_[b, self.params.z] if b.shape == (2,) else b  # type: ignore[attr-defined]

    def bind_belief(self, belief_at: Callable[[float], Belief | None]) -> None:
        """fusion.api.ReadsBelief: the run loop's ``belief_at(t)``, the filter's belief predicted to t."""
        self._belief_at = belief_at

    def _take_input(self, t: float | None, u: np.ndarray | None) -> None:
        """fusion.api.UsesInput (input_acceleration): the latest IMU sample ``ax ay az gx gy gz`` (FRD)."""
        self._u = None if u is None else np.asarray(u, dtype=float)

    def feed(self, message: Message) -> list[Message]:
        """Take one ``beacon range`` message (or several pairs); return the fixes of the cycles it closes."""
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
                raise MalformedMessage(f"range to {label} {rng} m beyond {MAX_MAGNITUDE:g} (its square overflows)")
            if self.params.max_range is not None and rng > self.params.max_range:  # type: ignore[attr-defined]
                raise MalformedMessage(f"range to {label} {rng} m beyond max_range "
                                       f"{self.params.max_range} m")  # type: ignore[attr-defined]
            pairs.append((label, rng))
        if len(pairs) > 1 and len({label for label, _ in pairs}) != len(pairs):
            raise MalformedMessage(f"beacon named twice in one message {vals!r}")
        self._sensor, self._line = message.sensor, message.line
        out: list[Message] = []
        for label, rng in pairs:
            for cycle in self.schedule.add(message.t, label, rng):
                out += self._solve(cycle)
        self._schedule_events()
        if self.schedule.open_beacons() == len(self.beacon_positions):   # every expected beacon heard
            out += self._solve(self.schedule.close_open())
        return out

    def flush(self) -> list[Message]:
        """The fixes of the cycles still gathered (end of input)."""
        out: list[Message] = []
        for cycle in self.schedule.flush():
            out += self._solve(cycle)
        self._schedule_events()
        return out

    def _schedule_events(self) -> None:
        """The firing schedule's news as events: a second report of one pulse dropped (``rejected``, counted
        ``duplicate_pulses``), a period that could not be learnt (``warning``)."""
        for drop, keep in self.schedule.take_duplicates():
            self.counters["duplicate_pulses"] = self.counters.get("duplicate_pulses", 0) + 1
            self.events.append(Event(drop[0], "rejected", self._sensor,
                                     f"range to {drop[1]} ({drop[2]:.3f} m, t={drop[0]:.6f} s) is a second report "
                                     f"of the pulse of {keep[2]:.3f} m (t={keep[0]:.6f} s), emitted "
                                     f"{1e3 * abs(drop[3] - keep[3]):.3g} ms apart; the shorter (the direct "
                                     f"path) is kept"))
        for late in self.schedule.take_late():
            self.counters["late_ranges"] = self.counters.get("late_ranges", 0) + 1
            self.events.append(Event(late[0], "rejected", self._sensor,
                                     f"range to {late[1]} ({late[2]:.3f} m, t={late[0]:.6f} s) came after its cycle "
                                     f"was closed at the last slot heard before (the beacon came into reach); "
                                     f"expected from the next cycle on"))
        for t, why in self.schedule.take_warnings():
            self.events.append(Event(t, "warning", self._sensor, f"ols_trilateration: {why}"))

    def _solve(self, cycle: list) -> list[Message]:
        """Fix of one closed cycle of (t, beacon, range, t_emit)."""
        p: OlsParams = self.params  # type: ignore[assignment]
        self.counters["cycles"] += 1
        self.counters["split_cycles"] = self.schedule.splits
        names = [c[1] for c in cycle]
        times = np.array([c[0] for c in cycle])
        ranges = np.array([c[2] for c in cycle])
        B = np.array([self.beacon_positions[n] for n in names])
        t_end = float(max([c[0] for c in cycle]))     # the largest stamp (max of a list: no numpy reduction)
        t_m = float(times.sum()) / len(times)
        t_fix, age = t_m, 0.0
        v, Pv, start, acc = None, None, None, None
        B0 = B
        compensated = len(names) >= self.min_beacons and p.motion_compensation
        if compensated:
            v, Pv, t_fix, start, acc = self._velocity(t_m)
            age = t_fix - t_m
            dt = times - t_m
            if acc is None:
                B = B - dt[:, None] * v
            else:       # the velocity at t_m and the acceleration within the cycle, from the IMU
                B = B - dt[:, None] * (v - age * acc) - (0.5 * dt * dt)[:, None] * acc
            # v is the belief's at t_fix: off the velocity at t_m by the acceleration over the age, which the
            # range covariance carries (velocity_age); the position model bridges the age itself
        elif len(names) >= self.min_beacons and len(names) > 1:
            Pv = self._prior_velocity_cov()
        try:
            if len(names) < self.min_beacons:
                raise NoFix("too_few_beacons", f"{len(names)} beacon(s) {names}, need {self.min_beacons}")
            try:
                pos, cov, info = self._trilaterate(B, ranges, times - t_m, Pv, start, 0.0 if acc is not None else age)
            except NoFix as exc:
                # Lost lock: after a gap the belief can be metres and m/s off, its velocity then spoils the
                # compensation and every cycle is refused (the fix that would correct the belief refused
                # because of the belief). After REACQUIRE_AFTER refused cycles in a row the cycle is solved
                # as without a belief (v = 0, sd prior_speed_sd; Gauss-Newton from the beacons' geometry).
                if not (compensated and exc.reason == "inconsistent" and self._refused >= REACQUIRE_AFTER - 1):
                    raise
                B, Pv, t_fix, age, start = B0, self._prior_velocity_cov(), t_m, 0.0, None
                pos, cov, info = self._trilaterate(B, ranges, times - t_m, Pv, None)
                self.counters["reacquired"] = self.counters.get("reacquired", 0) + 1
                self.events.append(Event(t_end, "reacquired", self._sensor, f"fix without the belief's velocity after "
                                         f"{self._refused} cycles refused in a row (lost lock)"))
            total = float(pos.sum()) + float(cov.sum())   # a nan or inf propagates; an overflow is checked below
            if total - total != 0.0 and not (np.all(np.isfinite(pos)) and np.all(np.isfinite(cov))):
                raise NoFix("inconsistent", f"the fix is not finite (ranges {ranges.tolist()} m)")
        except NoFix as exc:
            if exc.reason == "inconsistent":
                self._refused += 1
            self.counters[exc.reason] += 1
            self.events.append(Event(t_end, "no_fix", self._sensor, str(exc)))
            return []
        except (np.linalg.LinAlgError, ValueError) as exc:  # numbers no fix can come from (not finite)
            self.counters["inconsistent"] += 1
            self.events.append(Event(t_end, "no_fix", self._sensor, f"inconsistent: no fix from ranges "
                                     f"{ranges.tolist()} m: {exc}"))
            return []
        for j in info["rejected"]:
            self.counters["outliers_removed"] += 1
            self.events.append(Event(float(times[j]), "rejected", self._sensor,
                                     f"range to {names[j]} ({ranges[j]:.3f} m) inconsistent with the others; "
                                     f"fix from {len(info['used'])} beacons"))
        self._refused = 0
        self.counters["fixes"] += 1
        self.counters["qr"] += info["method"].startswith("qr")
        self.last_fix = (t_m, pos, cov, info)
        # the fix as a typed value (the position model's observe takes it); the covariance mirrored from its
        # upper triangle, as a fix line of a recording (pack_fix) is read
        cov = cov.copy()
        cov[_LOWER3] = cov.T[_LOWER3]          # = np.triu(cov) + np.triu(cov, 1).T, without the two triu calls
        return [Fix(t_fix, np.asarray(pos, dtype=float), cov, float(age) if age > 0.0 else 0.0,
                    tuple(names[j] for j in info["used"]), self._sensor, self._line)]

    def _prior_velocity_cov(self) -> np.ndarray:
        """Without a usable belief: the receiver moved at an unknown velocity (sd prior_speed_sd) between the
        ranges; their offsets from t_m carry that as correlated range errors (an honest covariance)."""
        p: OlsParams = self.params  # type: ignore[assignment]
        return np.diag([p.prior_speed_sd ** 2] * 2 + [p.prior_speed_sd ** 2 if p.dim == 3 else 0.0])

    def _trilaterate(self, B: np.ndarray, ranges: np.ndarray, offsets: np.ndarray, Pv: np.ndarray | None,
                     start: np.ndarray | None, age: float = 0.0):
        p: OlsParams = self.params  # type: ignore[assignment]
        with np.errstate(over="ignore", invalid="ignore"):    # overflowing ranges: caught by the caller
            return trilaterate(
                B, ranges, dim=p.dim, z=p.z, z_sd=p.z_sd, sigma=p.range_sd, reference=p.reference,
                qr_condition=p.qr_condition, degenerate_condition=p.degenerate_condition,
                refine=p.refine_iterations, consistency_probability=p.consistency_probability,
                max_outliers=p.max_outliers, min_beacons=self.min_beacons,
                offsets=None if Pv is None else offsets, velocity_cov=Pv,
                accel_sd=p.accel_sd if Pv is not None else 0.0, solve_height=p.solve_height,
                inflate_misfit=p.inflate_misfit, start=start if p.refine_iterations else None, velocity_age=age)

    def _velocity(self, t: float) -> tuple[np.ndarray, np.ndarray, float, np.ndarray | None, np.ndarray | None]:
        """From the filter's belief predicted to ``t``: the velocity (3,) (m/s, navigation frame), its
        covariance (3, 3) with the unmodelled part, the belief's time (>= t), the receiver position it
        predicts at ``t`` (p + C_b^n r, m: where Gauss-Newton starts, in the basin of the filter's estimate
        rather than a mirror image of the beacons' geometry) and, with ``input_acceleration``, the
        acceleration (3,) (m/s^2, navigation frame) of the latest input sample; without a belief v = 0, no
        start and no acceleration."""
        p: OlsParams = self.params  # type: ignore[assignment]
        belief = self._belief_at(t) if self._belief_at is not None else None
        extra = np.diag([p.velocity_sd ** 2] * 3)
        if belief is None or self._v is None:
            return np.zeros(3), np.diag([p.prior_speed_sd ** 2] * 3), t, None, None
        sl = self._v
        n = sl.stop - sl.start
        x = belief.x
        v = np.zeros(3)
        v[:n] = x[sl]
        Pv = extra
        if belief.S is not None and belief.P is None:
            Sv = belief.S[sl]
            Pv[:n, :n] += Sv @ Sv.T
        else:
            Pv[:n, :n] += belief.P[sl, sl]  # type: ignore[index]
        t_b = max(float(belief.t), t)
        acc = None
        if p.input_acceleration and self._u is not None:
            f = self._u[:3] - (x[self._ba] if self._ba is not None else 0.0)
            acc = _rotate(x[self._qa], f) + np.array([0.0, 0.0, p.gravity])
        start = None
        if self._p is not None:
            ps = self._p
            start = np.full(3, p.z)
            start[:ps.stop - ps.start] = x[ps]
            if self._q is not None:
                start = start + _rotate(x[self._q], self._arm)
            start = start - v * (t_b - t)                 # back to t (inputs past t already integrated)
            if acc is not None:
                start = start + 0.5 * (t_b - t) ** 2 * acc
            if p.dim == 2:
                start[2] = p.z
        self.counters["compensated"] += 1
        return v, Pv, t_b, start, acc
