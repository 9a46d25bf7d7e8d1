"""Process ``pv``: n-D constant velocity (white-noise acceleration), paper 001 eqs. 3-4.

State ``p:n v:n`` (m, m/s; any Cartesian frame, NED in 3-D). Per axis i with spectral density S_i
(m^2/s^3, the PSD of the white acceleration):

.. math::
    F = \\begin{bmatrix} I & \\Delta t\\, I \\\\ 0 & I \\end{bmatrix},\\qquad
    Q_i = S_i \\begin{bmatrix} \\Delta t^3/3 & \\Delta t^2/2 \\\\ \\Delta t^2/2 & \\Delta t \\end{bmatrix}
"""
from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator

from fusion.api import Block, Params, ProcessModel, StateLayout


MAX_SPECTRAL_DENSITY = 1e12


class ConstantVelocity(ProcessModel):
    """n-D constant-velocity model (paper 001 eq. 4); state p:n v:n in m and m/s.

    Params: ``dims`` (1-3), ``spectral_density``: S per axis in m^2/s^3 (scalar or one per axis)."""

    name = "pv"
    linear = True

    class Params(Params):
        dims: int = Field(2, ge=1, le=3, description="number of axes (2: plane, 3: space)")
        spectral_density: float | list[float] = Field(1.0, description="S_v per axis, m^2/s^3")

        @model_validator(mode="after")
        def _check(self):
            s = np.atleast_1d(np.asarray(self.spectral_density, float))
            if s.size not in (1, self.dims):
                raise ValueError(f"spectral_density needs {'1 value' if self.dims == 1 else f'1 or {self.dims} values'}, got {s.size}")
            if np.any(s < 0):
                raise ValueError("spectral_density must be >= 0")
            if np.any(s > MAX_SPECTRAL_DENSITY):
                raise ValueError(f"spectral_density must be at most {MAX_SPECTRAL_DENSITY:g} m^2/s^3 (an "
                                 "acceleration sd of 1e6 m/s^2 over 1 s); beyond, the covariance overflows")
            return self

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        d = self.params.dims
        self.layout = StateLayout([Block("p", d), Block("v", d)])
        self._S = np.broadcast_to(np.asarray(self.params.spectral_density, float), (d,)).copy()
        # F and Q depend on dt alone, and a stream repeats a few dt values (sensor periods): memoised
        # per dt, read-only (rebuilding them would be a large share of a UKF step).
        self._F_cache: dict[float, np.ndarray] = {}
        self._Q_cache: dict[float, np.ndarray] = {}

    _CACHE_MAX = 64  # distinct dt values kept (jittered stamps give many; the cache then starts over)

    def F(self, dt: float) -> np.ndarray:
        """Transition matrix (2d, 2d) over dt seconds (read-only)."""
        F = self._F_cache.get(dt)
        if F is None:
            d = self.params.dims
            F = np.eye(2 * d)
            F[:d, d:] = dt * np.eye(d)
            F.setflags(write=False)
            if len(self._F_cache) >= self._CACHE_MAX:
                self._F_cache.clear()
            self._F_cache[dt] = F
        return F

    def f(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        d = self.params.dims
        out = np.array(x, dtype=float, copy=True)
        out[..., :d] += dt * out[..., d:]
        return out

    def jacobian(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        return self.F(dt)

    def Q(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """Discrete process noise (2d, 2d) over dt seconds, eq. 4 (read-only)."""
        Q = self._Q_cache.get(dt)
        if Q is None:
            d = self.params.dims
            Q = np.zeros((2 * d, 2 * d))
            idx = np.arange(d)
            Q[idx, idx] = self._S * dt ** 3 / 3
            Q[idx, idx + d] = Q[idx + d, idx] = self._S * dt ** 2 / 2
            Q[idx + d, idx + d] = self._S * dt
            Q.setflags(write=False)
            if len(self._Q_cache) >= self._CACHE_MAX:
                self._Q_cache.clear()
            self._Q_cache[dt] = Q
        return Q

    # batched filters (fusion.batch): F and Q depend on dt alone, one shared matrix for all N states
    def jacobian_batch(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """F (2d, 2d) shared by the states x (N, 2d) (broadcasts against (N, 2d, 2d))."""
        return self.F(dt)

    def Q_batch(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """Q (2d, 2d) over dt seconds shared by the states x (N, 2d) (broadcasts against (N, 2d, 2d))."""
        return self.Q(x, u, dt)
