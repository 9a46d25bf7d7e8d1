"""A truth drawn from the constant-velocity (white-acceleration) model itself: the ``pv`` process's motion.

Per axis the state [p, v] (m, m/s; the scenario's frame, NED in 3-D) follows ``p' = v``, ``v' = w`` with
``w`` white acceleration of power spectral density q (``spectral_density``, m^2/s^3). On the grid
``t_k = k h`` (h = ``step``) it is drawn exactly from the discretised model (paper 001 eqs. 3-4, the ``pv``
process's F and Q)::

    x_{k+1} = F x_k + w_k,  F = [[1, h], [0, 1]],  w_k ~ N(0, Q),  Q = q [[h^3/3, h^2/2], [h^2/2, h]]

from an initial state drawn around ``start`` / ``start_velocity`` with ``start_sd`` / ``start_velocity_sd``
(the filter's prior, for a matched control). Between two grid points the motion is the cubic Hermite
through their positions and velocities, so at every grid time the truth is exactly the model's draw and a
sensor sampled on the grid sees the model; the acceleration is that cubic's (piecewise linear).

Areas (``bounds``): a walk of the model does not stay in a room (its velocity spreads as sqrt(q t)), so
either ``redraw``: the whole walk is drawn again from the same generator until every grid position is
inside (at most ``max_draws`` draws; the truth is then the model conditioned on staying inside, which
favours the slower walks), or ``reflect``: the free walk is folded into the area (a wall mirrors the
position and flips the velocity's normal component: an elastic bounce, an impulse the model does not have).
The number of draws is ``draws``. Attitude: level, heading north, no rotation (the model states none).
"""
from __future__ import annotations

import numpy as np

from fusion.simulate.kinematics import Kinematics
from fusion.simulate.scenario import WhiteAccelerationTrajectory as WhiteAccelerationSpec

MAX_STEPS = 5e7   # grid points of one walk (held in memory)


class WhiteAccelerationError(ValueError):
    """The spec cannot be realised (message names the field)."""


def transition(q: float, h: float) -> tuple[np.ndarray, np.ndarray]:
    """F (2, 2) and Q (2, 2) of one axis over h seconds for white acceleration of PSD q (m^2/s^3)."""
    F = np.array([[1.0, h], [0.0, 1.0]])
    Q = q * np.array([[h ** 3 / 3.0, h ** 2 / 2.0], [h ** 2 / 2.0, h]])
    return F, Q


class WhiteAccelerationTrajectory:
    """The walk of the module docstring; ``sample(t)`` gives the Kinematics at any times in [0, duration]."""

    def __init__(self, spec: WhiteAccelerationSpec, dim: int = 3, duration: float | None = None):
        n_ax = len(spec.start)
        if n_ax != dim:
            raise WhiteAccelerationError(f"trajectory.start: a {dim}-D scenario has {dim} coordinates, got {n_ax}")
        v0 = np.zeros(n_ax) if spec.start_velocity is None else np.array(spec.start_velocity, float)
        if v0.shape != (n_ax,):
            raise WhiteAccelerationError(f"trajectory.start_velocity: expected {n_ax} values, got {v0.size}")
        if duration is not None and duration > spec.duration + 1e-9:
            raise WhiteAccelerationError(f"duration: {duration:g} s is longer than trajectory.duration "
                                         f"({spec.duration:g} s)")
        n = int(np.ceil(spec.duration / spec.step - 1e-9))
        if n > MAX_STEPS:
            raise WhiteAccelerationError(f"trajectory.step: {n:.3g} grid points over {spec.duration:g} s; at most "
                                         f"{MAX_STEPS:g} (a longer step)")
        p0 = np.array(spec.start, float)
        lo = hi = None
        if spec.bounds is not None:
            b = np.array(spec.bounds, float)
            if b.shape != (n_ax, 2) or np.any(b[:, 0] >= b[:, 1]):
                raise WhiteAccelerationError(f"trajectory.bounds: expected {n_ax} pairs [min, max] with min < max")
            lo, hi = b[:, 0], b[:, 1]
            if np.any(p0 < lo) or np.any(p0 > hi):
                raise WhiteAccelerationError("trajectory.start: outside trajectory.bounds")
        self.spec, self.dim, self.h, self.n_axes = spec, dim, spec.step, n_ax
        self.duration = float(spec.duration)
        self._lo, self._hi = lo, hi
        rng = np.random.default_rng(spec.seed)
        _, Q = transition(spec.spectral_density, spec.step)
        L = np.linalg.cholesky(Q)
        self.draws = 0
        while True:
            self.draws += 1
            P, V = self._draw(rng, L, n, p0, v0)
            if lo is None or spec.boundary == "reflect" or self._inside(P):
                break
            if self.draws >= spec.max_draws:
                raise WhiteAccelerationError(
                    f"trajectory.max_draws: none of {spec.max_draws} walks stayed inside trajectory.bounds over "
                    f"{spec.duration:g} s (a shorter duration, a smaller spectral_density, wider bounds or "
                    "boundary: reflect)")
        self._P, self._V = P, V     # (n + 1, axes) grid states of the free (unfolded) walk

    def _draw(self, rng: np.random.Generator, L: np.ndarray, n: int, p0: np.ndarray, v0: np.ndarray):
        """One walk on the grid: positions and velocities (n + 1, axes), the initial state drawn first."""
        s = self.spec
        k = self.n_axes
        start_p = p0 + s.start_sd * rng.standard_normal(k)
        start_v = v0 + s.start_velocity_sd * rng.standard_normal(k)
        if self._lo is not None:   # the drawn start is kept inside the area (folded back in)
            start_p = self._fold(start_p[None, :], np.zeros((1, k)))[0][0]
        w = rng.standard_normal((n, k, 2)) @ L.T                     # (step, axis, [dp dv]) ~ N(0, Q)
        V = np.vstack([start_v, start_v + np.cumsum(w[:, :, 1], axis=0)])
        P = np.vstack([start_p, start_p + np.cumsum(self.h * V[:-1] + w[:, :, 0], axis=0)])
        return P, V

    def _inside(self, P: np.ndarray) -> bool:
        return bool(np.all(P >= self._lo) and np.all(P <= self._hi))

    def _fold(self, p: np.ndarray, *deriv: np.ndarray) -> tuple[np.ndarray, ...]:
        """The free walk folded into [lo, hi] per axis: mirrored positions, derivatives with flipped signs."""
        span = self._hi - self._lo
        y = np.mod(p - self._lo, 2.0 * span)
        mirrored = y > span
        out = (self._lo + np.where(mirrored, 2.0 * span - y, y),)
        return out + tuple(np.where(mirrored, -d, d) for d in deriv)

    def grid(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Grid times (n + 1,) s and the free walk's positions and velocities (n + 1, axes) there."""
        return np.arange(len(self._P)) * self.h, self._P, self._V

    def sample(self, t: np.ndarray) -> Kinematics:
        t = np.asarray(t, float)
        h = self.h
        k = np.clip(np.floor(t / h + 1e-9).astype(int), 0, len(self._P) - 2)
        u = ((t - k * h) / h)[:, None]
        p0, p1, v0, v1 = self._P[k], self._P[k + 1], self._V[k], self._V[k + 1]
        u2, u3 = u * u, u * u * u
        p = (2 * u3 - 3 * u2 + 1) * p0 + (u3 - 2 * u2 + u) * h * v0 + (3 * u2 - 2 * u3) * p1 + (u3 - u2) * h * v1
        v = ((6 * u2 - 6 * u) * p0 + (3 * u2 - 4 * u + 1) * h * v0 + (6 * u - 6 * u2) * p1
             + (3 * u2 - 2 * u) * h * v1) / h
        a = ((12 * u - 6) * p0 + (6 * u - 4) * h * v0 + (6 - 12 * u) * p1 + (6 * u - 2) * h * v1) / (h * h)
        if self._lo is not None and self.spec.boundary == "reflect":
            p, v, a = self._fold(p, v, a)
        pad = np.zeros((len(t), 3 - self.n_axes))
        zeros = np.zeros((len(t), 3))
        return Kinematics(t, np.hstack([p, pad]), np.hstack([v, pad]), np.hstack([a, pad]), zeros, zeros.copy())
