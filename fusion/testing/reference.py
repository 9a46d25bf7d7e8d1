"""Small reference models and a textbook Kalman filter, written independently of the plugins (test-only,
not registered): :class:`ConstantVelocity` (linear, paper 001 eq. 4), :class:`PositionMeasurement`
(linear), :class:`RangeMeasurement` (ranges to fixed beacons, paper 001 eq. 6), :class:`RejectAll`."""
from __future__ import annotations

from typing import Iterable

import numpy as np
from pydantic import Field

from fusion.api import Belief, Gate, GateDecision, MeasurementModel, Params, ProcessModel, StateLayout

__all__ = ["ConstantVelocity", "PositionMeasurement", "RangeMeasurement", "RejectAll", "reference_kf", "nees"]


# --------------------------------------------------------------------------- reference models
class ConstantVelocity(ProcessModel):
    """Constant velocity in ``dims`` axes, state ``p:dims v:dims`` (m, m/s), white-acceleration noise
    of spectral density ``q`` (m^2/s^3) per axis (paper 001 eqs. 3-4)::

        p' = p + v dt,  v' = v,   Q_axis = q [[dt^3/3, dt^2/2], [dt^2/2, dt]]

    ``analytic_jacobian: false`` makes ``jacobian`` return None (exercises numerical fallbacks)."""

    name = "test_cv"
    linear = True

    class Params(Params):
        dims: int = Field(2, ge=1, le=3)
        q: float = Field(0.5, ge=0.0, description="acceleration spectral density, m^2/s^3")
        analytic_jacobian: bool = True

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        d = self.params.dims
        self.layout = StateLayout.parse(f"p:{d} v:{d}")
        self.d = d
        self._cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def _matrices(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        m = self._cache.get(dt)
        if m is None:
            d, q = self.d, self.params.q
            F = np.eye(2 * d)
            F[:d, d:] = dt * np.eye(d)
            I = np.eye(d)
            Q = q * np.block([[dt ** 3 / 3 * I, dt ** 2 / 2 * I], [dt ** 2 / 2 * I, dt * I]])
            F.flags.writeable = Q.flags.writeable = False
            if len(self._cache) > 256:
                self._cache.clear()
            m = self._cache[dt] = (F, Q)
        return m

    def F(self, dt: float) -> np.ndarray:
        """The transition matrix (read-only, cached per dt)."""
        return self._matrices(dt)[0]

    def f(self, x, u, dt):
        return np.asarray(x, dtype=float) @ self._matrices(dt)[0].T

    def jacobian(self, x, u, dt):
        return self._matrices(dt)[0] if self.params.analytic_jacobian else None

    def Q(self, x, u, dt):
        return self._matrices(dt)[1]


class PositionMeasurement(MeasurementModel):
    """Direct position measurement ``z = p`` (m) of a state whose first ``dim`` elements are p."""

    name = "test_position"
    linear = True

    class Params(Params):
        dim: int = Field(2, ge=1, le=3)
        n: int = Field(4, ge=1, description="state dimension")

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        self.dim = self.params.dim
        self.H = np.eye(self.dim, self.params.n)

    def h(self, x):
        return np.asarray(x, dtype=float)[..., : self.dim].copy()

    def jacobian(self, x):
        return self.H


class RangeMeasurement(MeasurementModel):
    """Ranges (m) from the position ``p = x[:d]`` to each of the beacons (k, d) (paper 001 eq. 6)::

        z_j = |p - b_j|,   dz_j/dp = (p - b_j)^T / |p - b_j|

    ``beacons`` may also come from ``context.beacons``. ``analytic_jacobian: false`` -> None."""

    name = "test_range"

    class Params(Params):
        beacons: list[list[float]] | None = None
        n: int = Field(4, ge=1, description="state dimension")
        analytic_jacobian: bool = True

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        b = self.params.beacons
        if b is None:
            b = [list(v) for v in self.context.beacons.values()]
        self.beacons = np.asarray(b, dtype=float)
        self.dim = self.beacons.shape[0]
        self.d = self.beacons.shape[1]

    def h(self, x):
        diff = np.asarray(x)[..., None, : self.d] - self.beacons
        return np.sqrt((diff * diff).sum(axis=-1))

    def jacobian(self, x):
        if not self.params.analytic_jacobian:
            return None
        diff = np.asarray(x)[: self.d] - self.beacons
        H = np.zeros((self.dim, self.params.n))
        H[:, : self.d] = diff / np.sqrt((diff * diff).sum(axis=-1))[:, None]
        return H


class RejectAll(Gate):
    """A gate that rejects every measurement (for interface checks)."""

    name = "test_reject_all"

    def check(self, nis: float, dim: int, state: None = None) -> tuple[GateDecision, None]:
        return GateDecision(False, 0.0), None


# --------------------------------------------------------------------------- reference filter
def reference_kf(x: np.ndarray, P: np.ndarray, steps: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                      np.ndarray, np.ndarray]]):
    """Textbook linear Kalman filter, independent of the plugins: for each ``(F, Q, H, R, z)`` predict
    then update (Joseph form); yields ``(x, P)`` after each update."""
    x = np.array(x, dtype=float)
    P = np.array(P, dtype=float)
    for F, Q, H, R, z in steps:
        x = F @ x
        P = F @ P @ F.T + Q
        S = H @ P @ H.T + R
        K = np.linalg.solve(S, H @ P).T
        x = x + K @ (z - H @ x)
        A = np.eye(len(x)) - K @ H
        P = A @ P @ A.T + K @ R @ K.T
        P = (P + P.T) / 2
        yield x, P


def nees(x_true: np.ndarray, belief: Belief) -> float:
    """Normalised estimation error squared ``e^T P^-1 e``, e = x_true - x (chi-square, n dof)."""
    e = np.asarray(x_true, dtype=float) - belief.x
    return float(e @ np.linalg.solve(belief.cov, e))
