"""Trajectories: the true motion as exact functions of time (position, velocity, acceleration, attitude and
angular rate are mutually consistent, so an IMU derived from them integrates back to the truth).

* ``WaypointTrajectory``: a vehicle or pedestrian on a WaypointPath; runs between stops follow quintic
  speed ramps (continuous acceleration and jerk); heading along the path, pitch along its slope, no roll.
* ``RandomWalkTrajectory``: position and Euler angles random-walk by a step each interval, interpolated
  by quintic splines (C^4), blended in smoothly after a static start.
* ``WhiteAccelerationTrajectory`` (fusion.simulate.white_acceleration): the constant-velocity model's own
  motion, white acceleration of a given PSD drawn exactly on a grid (a matched truth for a ``pv`` filter).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_interp_spline

from fusion.simulate.kinematics import Kinematics
from fusion.simulate.path import PathError, WaypointPath
from fusion.simulate.profiles import H_PRIME_MAX, smoothstep, smoothstep_d1, smoothstep_d2, smoothstep_int
from fusion.simulate.scenario import RandomWalkTrajectory as RandomWalkSpec
from fusion.simulate.scenario import WaypointsTrajectory as WaypointsSpec
from fusion.simulate.scenario import WhiteAccelerationTrajectory as WhiteAccelerationSpec


class TrajectoryError(ValueError):
    """The trajectory spec cannot be realised (message names the field)."""


@dataclass(frozen=True)
class _Phase:
    """Speed from v1 to v2 over T seconds along a quintic smoothstep (v1 == v2: cruise or stand still)."""

    t0: float
    T: float
    s0: float
    v1: float
    v2: float

    @property
    def length(self) -> float:
        return 0.5 * (self.v1 + self.v2) * self.T


class WaypointTrajectory:
    """Motion along a WaypointPath with stops and corner speeds (see the module docstring).

    The speed profile is a chain of phases: standing still, cruising, or changing speed from v1 to v2 in
    ``T = 15/8 |v2 - v1| / max_accel`` seconds (peak acceleration max_accel), covering ``(v1 + v2) T / 2``
    metres. A run goes from rest (the start or a stop) to rest; a corner with ``turn_speed`` is driven at
    that speed from the start to the end of its turn; between those constraints the vehicle reaches the
    highest speed up to the cruise speed that leaves room to brake in time."""

    def __init__(self, spec: WaypointsSpec, dim: int = 3):
        pts = np.array([w.at[:2] for w in spec.waypoints], float)
        for i, w in enumerate(spec.waypoints):
            if dim == 2 and len(w.at) != 2:
                raise TrajectoryError(f"trajectory.waypoints.{i}: a 2-D scenario has [x, y] waypoints")
        heights = np.array([w.at[2] if len(w.at) == 3 else 0.0 for w in spec.waypoints])
        radii = np.array([spec.radius if w.radius is None else w.radius for w in spec.waypoints])
        try:
            self.path = WaypointPath(pts, radii, heights)
        except PathError as exc:
            raise TrajectoryError(f"trajectory.waypoints: {exc}") from None
        self.spec = spec
        self._amax = spec.max_accel
        n = len(spec.waypoints)
        phases: list[_Phase] = []
        t = 0.0
        if spec.static_start > 0:
            phases.append(_Phase(0.0, spec.static_start, 0.0, 0.0, 0.0))
            t = spec.static_start
        stops = [i for i, w in enumerate(spec.waypoints) if w.stop > 0 and 0 < i < n - 1]
        bounds = [0] + stops + [n - 1]
        for a, b in zip(bounds[:-1], bounds[1:]):
            V = spec.waypoints[a].speed or spec.speed
            # constraints (station, speed): rest at both ends, turn_speed over each corner turn in between
            cons: list[tuple[float, float, bool]] = [(self.path.stations[a], 0.0, False)]
            for i in range(a + 1, b):
                vz = spec.waypoints[i].turn_speed
                if vz is None:
                    continue
                z0, z1 = self.path.turn_span(i)
                cons += [(z0, vz, False), (z1, vz, True)]  # True: hold the speed from the previous point
            cons.append((self.path.stations[b], 0.0, False))
            for (s0, v1, _), (s1, v2, hold) in zip(cons[:-1], cons[1:]):
                t = self._segment(phases, t, s0, s1, v1, v2, V, hold, a, b)
            if b < n - 1 or spec.static_end > 0:
                rest = spec.waypoints[b].stop if b < n - 1 else spec.static_end
                phases.append(_Phase(t, rest, self.path.stations[b], 0.0, 0.0))
                t += rest
        self._phases = phases
        self._t0 = np.array([ph.t0 for ph in phases])
        self.duration = t

    def _ramp(self, u: float, w: float) -> float:
        return H_PRIME_MAX * abs(w - u) / self._amax

    def _segment(self, phases, t, s0, s1, v1, v2, V, hold, a, b) -> float:
        """Append the phases from (s0, v1) to (s1, v2); returns the end time."""
        L = s1 - s0
        if hold:  # through a corner at its turn speed
            if v1 > 0 and L > 0:
                phases.append(_Phase(t, L / v1, s0, v1, v1))
                t += L / v1
            return t
        # peak speed vp: ramps v1 -> vp -> v2 must fit in L:  15/16 (2 vp^2 - v1^2 - v2^2) / amax <= L
        vp = min(V, np.sqrt(max((L * self._amax / (0.5 * H_PRIME_MAX) + v1 * v1 + v2 * v2) / 2.0, 0.0)))
        if vp < max(v1, v2) - 1e-9:
            raise TrajectoryError(f"trajectory.waypoints {a}-{b}: no room to change speed from {v1:g} to "
                                  f"{v2:g} m/s in {L:.2f} m at max_accel {self._amax:g} m/s^2 (lower the "
                                  "turn_speed difference or raise max_accel)")
        vp = max(vp, v1, v2)
        T1, T2 = self._ramp(v1, vp), self._ramp(vp, v2)
        cruise = L - 0.5 * (v1 + vp) * T1 - 0.5 * (vp + v2) * T2
        for ph in (_Phase(t, T1, s0, v1, vp),
                   _Phase(t + T1, cruise / vp if vp > 0 else 0.0, s0 + 0.5 * (v1 + vp) * T1, vp, vp),
                   _Phase(t + T1 + (cruise / vp if vp > 0 else 0.0), T2, s1 - 0.5 * (vp + v2) * T2, vp, v2)):
            if ph.T > 1e-12:
                phases.append(ph)
                t = ph.t0 + ph.T
        return t

    # ------------------------------------------------------------------ speed profile
    def arc(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Station s (m), speed s' (m/s) and acceleration s'' (m/s^2) along the path at times t."""
        t = np.asarray(t, float)
        k = np.clip(np.searchsorted(self._t0, t, side="right") - 1, 0, len(self._phases) - 1)
        T = np.array([ph.T for ph in self._phases])[k]
        s0 = np.array([ph.s0 for ph in self._phases])[k]
        v1 = np.array([ph.v1 for ph in self._phases])[k]
        dv = np.array([ph.v2 - ph.v1 for ph in self._phases])[k]
        tau = np.clip(t - self._t0[k], 0.0, T)
        x = np.divide(tau, T, out=np.zeros_like(tau), where=T > 0)
        s = s0 + v1 * tau + dv * T * smoothstep_int(x)
        sd = v1 + dv * smoothstep(x)
        sdd = np.divide(dv * smoothstep_d1(x), T, out=np.zeros_like(tau), where=T > 0)
        return s, sd, sdd

    def sample(self, t: np.ndarray) -> Kinematics:
        t = np.asarray(t, float)
        s, sd, sdd = self.arc(t)
        psi, kap, _ = self.path.heading(s)
        xy = self.path.position(s)
        z, dz, ddz = self.path.height(s)
        c, sn = np.cos(psi), np.sin(psi)
        p = np.column_stack([xy, z])
        v = sd[:, None] * np.column_stack([c, sn, dz])
        a = sdd[:, None] * np.column_stack([c, sn, dz]) + (sd * sd)[:, None] * np.column_stack(
            [-kap * sn, kap * c, ddz])
        theta = np.arctan(-dz)
        euler = np.column_stack([np.zeros_like(t), theta, psi])
        rates = np.column_stack([np.zeros_like(t), -ddz * sd / (1.0 + dz * dz), kap * sd])
        return Kinematics(t, p, v, a, euler, rates)


class RandomWalkTrajectory:
    """Random walk in position and attitude, smoothed by quintic splines (see the module docstring)."""

    def __init__(self, spec: RandomWalkSpec, duration: float):
        rng = np.random.default_rng(spec.seed)
        h = spec.step_interval
        n_steps = int(np.ceil(max(duration - spec.static_start, 0.0) / h)) + 4
        p0 = np.array(spec.start, float)
        e0 = np.deg2rad(np.array(spec.start_attitude_deg, float))
        lo = hi = None
        if spec.bounds is not None:
            b = np.array(spec.bounds, float)
            if b.shape != (3, 2) or np.any(b[:, 0] >= b[:, 1]):
                raise TrajectoryError("trajectory.bounds: expected [[xmin, xmax], [ymin, ymax], [zmin, zmax]]")
            lo, hi = b[:, 0], b[:, 1]
            if np.any(p0 < lo) or np.any(p0 > hi):
                raise TrajectoryError("trajectory.start: outside trajectory.bounds")
        tilt = np.deg2rad(spec.max_tilt_deg)
        # knots: 3 still ones before the walk starts (holds the static start exactly), then the steps
        P = [p0] * 3
        E = [e0] * 3
        for _ in range(n_steps):
            p = P[-1] + rng.normal(0.0, spec.position_step_sd, 3)
            e = E[-1] + rng.normal(0.0, np.deg2rad(spec.angle_step_sd_deg), 3)
            if lo is not None:
                p = np.where(p < lo, 2 * lo - p, p)
                p = np.where(p > hi, 2 * hi - p, p)
            e[:2] = np.where(np.abs(e[:2]) > tilt, np.sign(e[:2]) * 2 * tilt - e[:2], e[:2])
            P.append(p)
            E.append(e)
        tk = spec.static_start + h * (np.arange(len(P)) - 2)
        self._t_still = spec.static_start
        self._blend = 2.0 * h
        self._p0, self._e0 = p0, e0
        self._ps = make_interp_spline(tk, np.array(P), k=5)
        self._es = make_interp_spline(tk, np.array(E), k=5)
        self.duration = duration

    def sample(self, t: np.ndarray) -> Kinematics:
        """The spline S(t) blended in from rest: p = p0 + w (S - p0) with w a quintic smoothstep over the
        first two steps after the static start, so the motion starts with continuous acceleration."""
        t = np.asarray(t, float)
        S, S1, S2 = self._ps(t), self._ps(t, 1), self._ps(t, 2)
        E, E1 = self._es(t), self._es(t, 1)
        x = (t - self._t_still) / self._blend
        w = smoothstep(x)[:, None]
        w1 = (smoothstep_d1(x) / self._blend)[:, None]
        w2 = (smoothstep_d2(x) / self._blend ** 2)[:, None]
        dP, dE = S - self._p0, E - self._e0
        p = self._p0 + w * dP
        v = w * S1 + w1 * dP
        a = w * S2 + 2 * w1 * S1 + w2 * dP
        e = self._e0 + w * dE
        de = w * E1 + w1 * dE
        return Kinematics(t, p, v, a, e, de)


def build_trajectory(spec, dim: int, duration: float | None):
    """The trajectory object of a scenario's ``trajectory`` spec."""
    if isinstance(spec, WaypointsSpec):
        return WaypointTrajectory(spec, dim)
    if isinstance(spec, RandomWalkSpec):
        if duration is None:
            raise TrajectoryError("duration: a random_walk trajectory needs the scenario's duration")
        return RandomWalkTrajectory(spec, duration)
    if isinstance(spec, WhiteAccelerationSpec):
        from fusion.simulate.white_acceleration import WhiteAccelerationError, WhiteAccelerationTrajectory

        try:
            return WhiteAccelerationTrajectory(spec, dim, duration)
        except WhiteAccelerationError as exc:
            raise TrajectoryError(str(exc)) from None
    raise TrajectoryError(f"trajectory.type: unknown {type(spec).__name__}")
