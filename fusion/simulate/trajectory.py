"""Trajectories: the true motion as exact functions of time (position, velocity, acceleration, attitude and
angular rate are mutually consistent, so an IMU derived from them integrates back to the truth).

* ``WaypointTrajectory``: a vehicle or pedestrian on a WaypointPath; runs between stops follow quintic
  speed ramps (continuous acceleration and jerk); heading along the path, pitch along its slope, no roll.
* ``RandomWalkTrajectory``: position and Euler angles random-walk by a step each interval, interpolated
  by quintic splines (C^4), held still during a static start.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_interp_spline

from fusion.simulate.kinematics import Kinematics
from fusion.simulate.path import PathError, WaypointPath
from fusion.simulate.profiles import H_PRIME_MAX, smoothstep, smoothstep_d1, smoothstep_int
from fusion.simulate.scenario import RandomWalkTrajectory as RandomWalkSpec
from fusion.simulate.scenario import WaypointsTrajectory as WaypointsSpec


class TrajectoryError(ValueError):
    """The trajectory spec cannot be realised (message names the field)."""


@dataclass(frozen=True)
class _Run:
    t0: float   # start time
    s0: float   # start station
    length: float
    speed: float
    ramp: float  # ramp time

    @property
    def duration(self) -> float:
        return self.length / self.speed + self.ramp


class WaypointTrajectory:
    """Motion along a WaypointPath with stops (see the module docstring)."""

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
        # runs: from the start or a stop to the next stop or the end
        runs: list[_Run] = []
        t = spec.static_start
        stops = [i for i, w in enumerate(spec.waypoints) if w.stop > 0 and 0 < i < len(spec.waypoints) - 1]
        bounds = [0] + stops + [len(spec.waypoints) - 1]
        self._stop_times: list[tuple[float, float]] = []
        for a, b in zip(bounds[:-1], bounds[1:]):
            s0, s1 = self.path.stations[a], self.path.stations[b]
            v = spec.waypoints[a].speed or spec.speed
            length = s1 - s0
            ramp = H_PRIME_MAX * v / spec.max_accel
            if length < v * ramp:  # too short to reach cruise speed: lower it
                v = np.sqrt(length * spec.max_accel / H_PRIME_MAX)
                ramp = H_PRIME_MAX * v / spec.max_accel
            run = _Run(t, s0, length, v, ramp)
            runs.append(run)
            t += run.duration + spec.waypoints[b].stop
        self._runs = runs
        self.duration = t + spec.static_end

    # ------------------------------------------------------------------ speed profile
    def arc(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Station s (m), speed s' (m/s) and acceleration s'' (m/s^2) along the path at times t."""
        t = np.asarray(t, float)
        s = np.zeros(t.shape)
        sd = np.zeros(t.shape)
        sdd = np.zeros(t.shape)
        for r in self._runs:
            s[t >= r.t0] = r.s0
            tau = t - r.t0
            m = (tau >= 0) & (tau < r.duration)
            if not m.any():
                continue
            tau = tau[m]
            V, T, L, D = r.speed, r.ramp, r.length, r.duration
            up, down = tau < T, tau > D - T
            mid = ~(up | down)
            ss, v, a = np.empty(tau.shape), np.empty(tau.shape), np.empty(tau.shape)
            x = tau[up] / T
            ss[up], v[up], a[up] = V * T * smoothstep_int(x), V * smoothstep(x), V * smoothstep_d1(x) / T
            ss[mid], v[mid], a[mid] = V * T / 2 + V * (tau[mid] - T), V, 0.0
            x = (D - tau[down]) / T
            ss[down], v[down], a[down] = L - V * T * smoothstep_int(x), V * smoothstep(x), -V * smoothstep_d1(x) / T
            s[m], sd[m], sdd[m] = r.s0 + ss, v, a
        last = self._runs[-1]
        s[t >= last.t0 + last.duration] = last.s0 + last.length
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
        self._p0, self._e0 = p0, e0
        self._ps = make_interp_spline(tk, np.array(P), k=5)
        self._es = make_interp_spline(tk, np.array(E), k=5)
        self.duration = duration

    def sample(self, t: np.ndarray) -> Kinematics:
        t = np.asarray(t, float)
        p, v, a = self._ps(t), self._ps(t, 1), self._ps(t, 2)
        e, de = self._es(t), self._es(t, 1)
        still = t < self._t_still - 1e-12
        p[still], v[still], a[still], e[still], de[still] = self._p0, 0.0, 0.0, self._e0, 0.0
        return Kinematics(t, p, v, a, e, de)


def build_trajectory(spec, dim: int, duration: float | None):
    """The trajectory object of a scenario's ``trajectory`` spec."""
    if isinstance(spec, WaypointsSpec):
        return WaypointTrajectory(spec, dim)
    if isinstance(spec, RandomWalkSpec):
        if duration is None:
            raise TrajectoryError("duration: a random_walk trajectory needs the scenario's duration")
        return RandomWalkTrajectory(spec, duration)
    raise TrajectoryError(f"trajectory.type: unknown {type(spec).__name__}")
