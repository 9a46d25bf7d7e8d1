"""Solver ``orientation_geometric``: the attitude from two beacon directions (paper 003 sec. 5.1, eqs. 12-17).

Given the arrival directions n1, n2 of two beacons in the body frame (receiver normals) and the unit
vectors b1, b2 from the robot to the same beacons in the navigation frame::

    T(v, v_ref)  = R_x^-1 R_y^-1 R_z(alpha) R_y R_x           (eq. 12: rotate v onto v_ref about v x v_ref)
    T_planes     = T(unit(n1 x n2), unit(b1 x b2))              (eq. 16: match the planes' normals)
    T_final      = T(T_planes unit(n1 + n2), unit(b1 + b2)) T_planes   (eq. 17: then the bisectors)

R_x, R_y (eqs. 13-14) turn the axis c = unit(v x v_ref) onto z, R_z (eq. 15) rotates by alpha, with
sin(alpha) = |v x v_ref| and cos(alpha) = v . v_ref. T_final maps body vectors to the navigation frame: its
columns are the robot's axes in the world frame (C_b^n). Of a cycle of four beacons, the pair used is the
one with the largest |sin| of the angle between its vectors (both the normals and the beacon directions:
the smaller of the two sines is maximised), since two parallel vectors define no plane.
"""
from __future__ import annotations

from itertools import combinations
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from fusion import quaternion as quat
from fusion.api import BuildContext, ConfigError, Event, Fix, MalformedMessage, Message, Params, Solver

from .tdoa_geometric import AgreeingFixes, NoFix, agreed_period, parse_arrival, period_initial_fix, tdoa_fix


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    if n < 1e-12:
        raise NoFix("degenerate", "zero vector (parallel directions)")
    return v / n


def axis_rotation(v: np.ndarray, v_ref: np.ndarray) -> np.ndarray:
    """T(v, v_ref) (3, 3): the rotation about v x v_ref taking unit v onto unit v_ref (eqs. 12-15)."""
    v, v_ref = _unit(np.asarray(v, float)), _unit(np.asarray(v_ref, float))
    axis = np.cross(v, v_ref)
    s, c = float(np.linalg.norm(axis)), float(v @ v_ref)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        # antiparallel: half a turn about any axis perpendicular to v
        e = np.eye(3)[int(np.argmin(np.abs(v)))]
        axis, s, c = np.cross(v, e), 0.0, -1.0
    cx, cy, cz = axis / np.linalg.norm(axis)
    d = np.hypot(cy, cz)
    Rx = np.eye(3) if d < 1e-12 else np.array([[1, 0, 0], [0, cz / d, -cy / d], [0, cy / d, cz / d]])  # eq. 13
    Ry = np.array([[d, 0, -cx], [0, 1, 0], [cx, 0, d]])                                             # eq. 14
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])                                               # eq. 15
    return Rx.T @ Ry.T @ Rz @ Ry @ Rx                                                               # eq. 12


def two_vector_attitude(n1, n2, b1, b2) -> np.ndarray:
    """C_b^n (3, 3) from two body directions n1, n2 and the matching navigation directions b1, b2
    (eqs. 16-17): planes first, then bisectors. Raises NoFix('degenerate') for parallel pairs."""
    n1, n2, b1, b2 = (_unit(np.asarray(v, float)) for v in (n1, n2, b1, b2))
    T_planes = axis_rotation(_unit(np.cross(n1, n2)), _unit(np.cross(b1, b2)))        # eq. 16
    return axis_rotation(T_planes @ _unit(n1 + n2), _unit(b1 + b2)) @ T_planes        # eq. 17


def best_pair(normals: np.ndarray, dirs: np.ndarray) -> tuple[int, int]:
    """Indices of the pair with the largest min(|sin(n_i, n_j)|, |sin(b_i, b_j)|)."""
    best, pair = -1.0, (0, 1)
    for i, j in combinations(range(len(normals)), 2):
        s = min(np.linalg.norm(np.cross(normals[i], normals[j])), np.linalg.norm(np.cross(dirs[i], dirs[j])))
        if s > best:
            best, pair = s, (i, j)
    return pair


def orientation_fix(normals: np.ndarray, dirs: np.ndarray, min_sin: float = 1e-6) -> np.ndarray:
    """C_b^n (3, 3) from k >= 2 body directions ``normals`` (k, 3) and navigation directions ``dirs`` (k, 3)
    of the same beacons, by the best-conditioned pair (eqs. 12-17)."""
    normals = np.asarray(normals, float)
    dirs = np.asarray(dirs, float)
    if len(normals) < 2:
        raise NoFix("too_few_beacons", f"{len(normals)} direction(s), need 2")
    i, j = best_pair(normals, dirs)
    s = min(np.linalg.norm(np.cross(normals[i], normals[j])), np.linalg.norm(np.cross(dirs[i], dirs[j])))
    if s < min_sin:
        raise NoFix("degenerate", "every pair of directions is parallel (one receiver heard all beacons)")
    return two_vector_attitude(normals[i], normals[j], dirs[i], dirs[j])


class OrientationParams(Params):
    """YAML parameters of ``orientation_geometric``."""

    period_s: float = Field(0.225, gt=0, description="inter-firing period T (s), for the position")
    speed_of_sound: float = Field(340.0, gt=0, description="c (m/s)")
    beacons: list[str] | None = Field(None, description="beacons in firing order (default: all)")
    position: tuple[float, float, float] | None = Field(None, description="known robot position (m); "
                                                        "default: the geometric TDOA fix of the same cycle")
    arrival_sd: float = Field(2.0e-4, gt=0, description="arrival-time sd (s), for the position covariance")
    attitude_sd_deg: float = Field(15.0, gt=0, description="sd per axis (deg) attached to an attitude fix "
                                   "(paper: mean error 15 deg)")
    output: Literal["fix", "initialise"] = Field("fix", description="fix: an attitude fix per cycle; "
                                                 "initialise: the first pose fix only (x y z, position "
                                                 "covariance, qw qx qy qz), then every arrival passed through")
    receivers: str | list[tuple[float, float, float]] | None = Field(
        None, description="receiver normals (body frame), as the direction model's: a list, an array's name or a "
        "file; none: the recording header's '# receiver N' lines")
    initialise_agree: int = Field(3, ge=1, description="initialise: only once this many consecutive TDOA "
                                  "fixes agree (chi-square, 99 %): echoes cannot place the filter")


class OrientationGeometric(Solver):
    """Geometric attitude fixes (paper 003 sec. 5.1) as a sensor preprocessor.

    Input: ``beacon arrival receiver`` messages. A cycle of one arrival per beacon (as ``tdoa_geometric``)
    gives the robot position (the TDOA fix of the cycle, or ``position``), the unit vectors to the beacons,
    and with the receivers' normals (``receivers``, else the recording header's; body frame) the attitude by
    :func:`orientation_fix`. Output: a :class:`fusion.api.Fix` stamped at the cycle's last arrival, its
    ``attitude`` the quaternion C_b^n with ``attitude_cov`` ``attitude_sd_deg``^2 per axis (rad^2), its
    ``value`` the position used (m) with its covariance (the ``attitude`` model observes it). With
    ``output: initialise`` only one initial state fix is emitted, once ``initialise_agree`` consecutive TDOA fixes
    agree (their mean, the time of the last firing and the attitude of the last cycle:
    :mod:`fusion_plugins.solvers.initial_fix`), then each arrival is passed through unchanged; the
    ``direction`` model observes that fix as the first update of a pose filter from a wide initial belief. No fix:
    ``counters`` counts the reason and ``events`` gets a ``no_fix`` Event."""

    name: ClassVar[str] = "orientation_geometric"
    Params: ClassVar[type[Params]] = OrientationParams

    def __init__(self, params: OrientationParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        from fusion_plugins.measurement.receiver_array import resolve_receivers

        p: OrientationParams = self.params  # type: ignore[assignment]
        names = p.beacons if p.beacons is not None else list(self.context.beacons)
        bad = [b for b in names if b not in self.context.beacons]
        if bad or len(names) < 2:
            raise ConfigError(f"orientation_geometric: unknown or too few beacons {names}")
        if p.position is None and len(names) < 4:
            raise ConfigError("orientation_geometric: without 'position' it needs 4 beacons (TDOA fix)")
        self.beacon_positions = {n: np.asarray(self.context.beacons[n], float) for n in names}
        self.normals, self._receivers_info = resolve_receivers(
            p.receivers, self.context, "orientation_geometric")
        self.counters = {"cycles": 0, "fixes": 0, "too_few_beacons": 0, "degenerate": 0, "no_convergence": 0}
        self.events: list[Event] = []
        self._cycle: dict[str, tuple[float, int, Message]] = {}
        self._previous = None
        self._initialised = False
        self._agree = AgreeingFixes(p.initialise_agree)

    def info(self) -> dict:
        """The summary's ``info`` (fusion.api.ReportsInfo): the receiver array used and where it came from."""
        out: dict = {"receiver_array": dict(self._receivers_info)}
        if self._initialised:
            out["start"] = (f"pose from the geometric fixes: position, firing time and period of the first "
                            f"{self.params.initialise_agree} agreeing cycles (eqs. 1-8), attitude by the geometric "  # type: ignore[attr-defined]
                            "orientation algorithm (eqs. 12-17) of the last")
        return out

    def feed(self, message: Message) -> list[Message | Fix]:
        if self._initialised:
            return [message]
        try:
            label, arrival, rec = self._parse(message)
        except MalformedMessage as exc:    # counted and reported, not raised: the run goes on
            self.counters["malformed"] = self.counters.get("malformed", 0) + 1
            self.events.append(Event(message.t, "malformed", message.sensor, f"line {message.line}: {exc}"))
            return []
        out: list[Message | Fix] = []
        if self._cycle and (label in self._cycle or arrival - min(a for a, _, _ in self._cycle.values())
                            >= len(self.beacon_positions) * self.params.period_s):  # type: ignore[attr-defined]
            out += self._close()
        self._cycle[label] = (arrival, rec, message)
        if len(self._cycle) == len(self.beacon_positions):
            out += self._close()
        return out

    def _parse(self, message: Message) -> tuple[str, float, int]:
        label, arrival = parse_arrival(message, self.beacon_positions)
        if len(message.values) != 3:
            raise MalformedMessage("orientation_geometric expects 'beacon arrival receiver'")
        try:
            rec = float(message.values[2])
        except (TypeError, ValueError):
            raise MalformedMessage(f"receiver is not a number: {message.values[2]!r}") from None
        if rec != int(rec) or not 1 <= rec <= len(self.normals):
            raise MalformedMessage(f"receiver must be 1-{len(self.normals)}, got {message.values[2]!r}")
        return label, arrival, int(rec)

    def _close(self) -> list[Message | Fix]:
        p: OrientationParams = self.params  # type: ignore[assignment]
        cycle, self._cycle = self._cycle, {}
        names = sorted(cycle, key=lambda n: cycle[n][0])
        a = np.array([cycle[n][0] for n in names])
        B = np.array([self.beacon_positions[n] for n in names])
        last = cycle[names[-1]][2]
        self.counters["cycles"] += 1
        try:
            if p.position is not None:
                r, cov = np.asarray(p.position, float), np.eye(3) * 1e-6
            else:
                start = self._previous if self._previous is not None else B.mean(axis=0)
                r, cov, _ = tdoa_fix(B, a, np.rint((a - a[0]) / p.period_s), p.period_s, p.speed_of_sound,
                                     start, p.arrival_sd)
                self._previous = r
            dirs = (B - r) / np.linalg.norm(B - r, axis=1, keepdims=True)
            C = orientation_fix(self.normals[[cycle[n][1] - 1 for n in names]], dirs)
        except NoFix as exc:
            self.counters[exc.reason] += 1
            self._previous = None
            self._agree.reset()
            self.events.append(Event(float(a[-1]), "no_fix", last.sensor, f"orientation_geometric: {exc}"))
            return []
        self.counters["fixes"] += 1
        q = quat.from_matrix(C)
        sd = float(np.deg2rad(p.attitude_sd_deg))
        where = {"sensor": last.sensor, "line": last.line, "used": tuple(names)}
        if p.output == "initialise":
            from .initial_fix import initial_fix
            agreed = self._agree.add(r, cov, (names, a))
            if agreed is None:
                return []
            r, cov = agreed
            self._initialised = True
            period = None if p.position is not None else agreed_period(
                self._agree.agreeing(), self.beacon_positions, p.period_s, p.speed_of_sound, p.arrival_sd,
                np.mean(list(self.beacon_positions.values()), axis=0))
            if period is not None:     # the period estimated from the agreeing cycles (tdoa_geometric)
                return [period_initial_fix(period, float(a[-1]), q, sd, **where)]
            return [initial_fix(r, cov, B[-1], float(a[-1]), p.speed_of_sound, p.arrival_sd, q, sd, **where)]
        return [Fix(float(a[-1]), np.array(r, dtype=float), cov, attitude=q, attitude_cov=sd ** 2 * np.eye(3),
                    **where)]
