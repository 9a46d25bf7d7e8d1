"""Solver ``triad``: attitude from two vectors, gravity and the magnetic field (paper 002 eq. 7, sec. 3.1).

Functions (vectorised over leading axes, shapes ``(..., 3)``):

* :func:`triad` - TRIAD (Black 1964; Shuster & Oh 1981), the orthonormalised form of eq. 7: the triads
  ``t1 = r1/|r1|, t2 = (r1 x r2)/|r1 x r2|, t3 = t1 x t2`` of the reference vectors (NED) and of the
  body vectors (FRD) give ``C_b^n = [t1 t2 t3]_n [t1 t2 t3]_b^T``. The first vector (gravity) is
  matched exactly, the second only in the plane they span.
* :func:`improved_triad` - the two TRIAD solutions anchored on either vector, averaged with weights
  ``sigma_2^2 : sigma_1^2`` (the anchor of the more accurate vector dominates) and brought back to a
  rotation by the polar decomposition (SVD). This is the optimised TRIAD of Bar-Itzhack & Harman (1996);
  it is our reading of the "Improved TRIAD" of Li and Yuan (2005) that paper 002 uses (sec. 2.3), whose
  text we could not check. For equal weights and exact vectors both are exact.
* :func:`attitude_covariance` - the covariance (3, 3) of the navigation-frame attitude error ``d theta``
  (``C_est = exp([d theta x]) C_true``, rad^2) propagated from the covariances of the two body vectors
  (their sensors' noise) through the algorithm, to first order: ``P = J1 S1 J1^T + J2 S2 J2^T`` with
  ``J = d(d theta)/d(b)`` by central differences on one vectorised batch. (Paper 002 left this to future
  work, sec. 3.)

Component ``triad`` (a preprocessor of the magnetometer sensor): each magnetometer sample and the
accelerometer's specific force at its time (the held IMU sample, through the ``take_input`` capability,
fusion.api.UsesInput) give an attitude fix, a :class:`fusion.api.Fix` with the ``attitude`` quaternion and
its ``attitude_cov`` (3, 3) (rad^2, navigation frame), for the ``attitude`` measurement. A static accelerometer reads
``f_b = -C_n^b g_n``: the body "gravity" is ``-f_b`` and the reference is ``g_n = [0, 0, g]``. When the
vehicle accelerates, ``f_b`` is not ``-g_b`` (paper 002 sec. 2.3): ``accel_disturbance_sd`` widens the
accelerometer's covariance accordingly.
"""
from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from fusion import quaternion as quat
from fusion.api import BuildContext, Event, Fix, MalformedMessage, Message, Params, Solver

__all__ = ["triad", "improved_triad", "attitude_covariance", "solve", "TriadSolver"]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _frame(v1: np.ndarray, v2: np.ndarray) -> np.ndarray:
    """Orthonormal triads (..., 3, 3), columns t1 t2 t3, anchored on v1."""
    t1 = _unit(v1)
    t2 = _unit(np.cross(v1, v2))
    return np.stack([t1, t2, np.cross(t1, t2)], axis=-1)


def triad(b1: np.ndarray, b2: np.ndarray, r1: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """C_b^n (..., 3, 3) from body vectors b1, b2 (FRD) and their references r1, r2 (NED), anchored on
    the first pair (eq. 7, orthonormalised)."""
    b1, b2, r1, r2 = (np.asarray(a, dtype=float) for a in (b1, b2, r1, r2))
    return _frame(r1, r2) @ np.swapaxes(_frame(b1, b2), -1, -2)


def _polar(A: np.ndarray) -> np.ndarray:
    """The rotation nearest to A (..., 3, 3) (Frobenius), by SVD with the determinant fixed to +1."""
    U, _, Vt = np.linalg.svd(A)
    d = np.sign(np.linalg.det(U @ Vt))
    U = U.copy()
    U[..., :, 2] *= d[..., None]
    return U @ Vt


def improved_triad(b1: np.ndarray, b2: np.ndarray, r1: np.ndarray, r2: np.ndarray,
                   sigma1: float | np.ndarray = 1.0, sigma2: float | np.ndarray = 1.0) -> np.ndarray:
    """C_b^n (..., 3, 3): the TRIAD anchored on each vector, weighted by the other's angular variance
    (sigma_i: angular sd of direction i, rad), orthonormalised (module docstring)."""
    b1, b2, r1, r2 = (np.asarray(a, dtype=float) for a in (b1, b2, r1, r2))
    A1 = triad(b1, b2, r1, r2)
    A2 = triad(b2, b1, r2, r1)
    s1, s2 = np.asarray(sigma1, float) ** 2, np.asarray(sigma2, float) ** 2
    w1 = (s2 / (s1 + s2))[..., None, None]
    return _polar(w1 * A1 + (1.0 - w1) * A2)


def _rotvec_of(C: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) of rotation matrices near I (the skew part, exact to second order)."""
    return 0.5 * np.stack([C[..., 2, 1] - C[..., 1, 2], C[..., 0, 2] - C[..., 2, 0], C[..., 1, 0] - C[..., 0, 1]], axis=-1)


def solve(method: str, b1, b2, r1, r2, sigma1: float = 1.0, sigma2: float = 1.0) -> np.ndarray:
    """C_b^n by ``method`` ``triad`` or ``improved_triad``."""
    if method == "triad":
        return triad(b1, b2, r1, r2)
    if method == "improved_triad":
        return improved_triad(b1, b2, r1, r2, sigma1, sigma2)
    raise ValueError(f"unknown method {method!r} (triad, improved_triad)")


def attitude_covariance(method: str, b1: np.ndarray, b2: np.ndarray, r1: np.ndarray, r2: np.ndarray,
                        S1: np.ndarray, S2: np.ndarray, C: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(P, J1): covariance (3, 3) (rad^2, navigation frame) of the attitude error from the covariances S1,
    S2 (3, 3) of the body vectors b1, b2 (their units), and J1 = d(d theta)/d b1 (3, 3) (for the
    correlation with an accelerometer bias). First order, central differences (one batch of 12 solves)."""
    b1, b2 = np.asarray(b1, float), np.asarray(b2, float)
    s1 = float(np.sqrt(np.trace(S1) / 3.0)) / np.linalg.norm(b1)
    s2 = float(np.sqrt(np.trace(S2) / 3.0)) / np.linalg.norm(b2)
    if C is None:
        C = solve(method, b1, b2, r1, r2, s1, s2)
    h1 = 1e-6 * np.linalg.norm(b1)
    h2 = 1e-6 * np.linalg.norm(b2)
    E = np.eye(3)
    B1 = np.concatenate([b1 + h1 * E, b1 - h1 * E, np.broadcast_to(b1, (6, 3))])
    B2 = np.concatenate([np.broadcast_to(b2, (6, 3)), b2 + h2 * E, b2 - h2 * E])
    Cs = solve(method, B1, B2, r1, r2, s1, s2)
    d = _rotvec_of(Cs @ C.T)                                 # (12, 3): d theta of each perturbed solve
    J1 = ((d[0:3] - d[3:6]) / (2 * h1)).T
    J2 = ((d[6:9] - d[9:12]) / (2 * h2)).T
    P = J1 @ S1 @ J1.T + J2 @ S2 @ J2.T
    return 0.5 * (P + P.T), J1


class TriadParams(Params):
    """YAML parameters of ``triad``."""

    method: Literal["triad", "improved_triad"] = Field("improved_triad", description="eq. 7, or Li and Yuan's "
                                                       "improvement (module docstring)")
    declination_deg: float | None = Field(None, ge=-180, le=180)
    inclination_deg: float | None = Field(None, ge=-90, le=90)
    intensity: float | None = Field(None, gt=0)
    field_ned: tuple[float, float, float] | None = Field(None, description="reference field m_n (NED)")
    gravity: float = Field(9.80665, gt=0, description="g (m/s^2): the reference g_n = [0, 0, g]")
    accel_sd: float = Field(0.03, gt=0, description="accelerometer noise per sample (m/s^2, per axis)")
    accel_disturbance_sd: float = Field(0.5, ge=0, description="vehicle acceleration not known to the "
                                        "solver (m/s^2, per axis): f_b != -g_b when moving")
    mag_sd: float = Field(0.2, gt=0, description="magnetometer noise (its units, per axis)")


class TriadSolver(Solver):
    """TRIAD / Improved TRIAD attitude fixes from the magnetometer and the held accelerometer sample
    (module docstring). Output: a :class:`fusion.api.Fix` of the attitude C_b^n (``attitude``, the
    quaternion) and the covariance of its navigation-frame error (``attitude_cov``, rad^2), stamped at the
    magnetometer sample."""

    name: ClassVar[str] = "triad"
    Params: ClassVar[type[Params]] = TriadParams

    def __init__(self, params: TriadParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        from fusion_plugins.measurement.earth_field import resolve_field
        from fusion_plugins.measurement.magnetometer import FieldParams
        p: TriadParams = self.params  # type: ignore[assignment]
        try:
            FieldParams(field_ned=p.field_ned, declination_deg=p.declination_deg,
                        inclination_deg=p.inclination_deg, intensity=p.intensity)
        except ValueError as exc:
            raise ValueError(str(exc).splitlines()[-1]) from None
        self.m_n, self._info = resolve_field(p, self.context)
        self.g_n = np.array([0.0, 0.0, p.gravity])
        self.events: list = []
        self._f: np.ndarray | None = None
        sa2 = p.accel_sd ** 2 + p.accel_disturbance_sd ** 2
        self.S1 = np.eye(3) * sa2
        self.S2 = np.eye(3) * p.mag_sd ** 2

    def info(self) -> dict:
        """The summary's ``info`` (fusion.api.ReportsInfo): where the reference field came from."""
        return {"reference_field": dict(self._info)}

    def take_input(self, t: float, u: np.ndarray | None) -> None:
        """The held IMU sample (fusion.api.UsesInput): its specific force (m/s^2, FRD)."""
        self._f = None if u is None else np.asarray(u, dtype=float)[:3]

    def feed(self, message: Message) -> list[Fix]:
        try:
            m_b = message.floats()
        except MalformedMessage as exc:
            m_b = np.full(1, np.nan)
            why = str(exc)
        else:
            why = f"expected 3 finite magnetometer values, got {message.values!r}"
        if m_b.shape != (3,) or not np.all(np.isfinite(m_b)):
            self.events.append(Event(message.t, "no_fix", message.sensor, f"line {message.line}: triad: {why}"))
            return []
        if self._f is None:
            return []                                        # no accelerometer sample yet
        g_b = -self._f
        if np.linalg.norm(np.cross(g_b, m_b)) < 1e-3 * np.linalg.norm(g_b) * np.linalg.norm(m_b):
            self.events.append(Event(message.t, "no_fix", message.sensor,
                                     "triad: gravity and magnetic field (nearly) parallel: no attitude"))
            return []
        C, P = self.solve(g_b, m_b)
        return [Fix(message.t, attitude=quat.from_matrix(C), attitude_cov=P, sensor=message.sensor,
                    line=message.line)]

    def solve(self, g_b: np.ndarray, m_b: np.ndarray, S1: np.ndarray | None = None,
              S2: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(C_b^n, P (3, 3)) from body gravity and field with the configured (or given) covariances."""
        S1 = self.S1 if S1 is None else S1
        S2 = self.S2 if S2 is None else S2
        p: TriadParams = self.params  # type: ignore[assignment]
        s1 = float(np.sqrt(S1[0, 0])) / np.linalg.norm(g_b)
        s2 = float(np.sqrt(S2[0, 0])) / np.linalg.norm(m_b)
        C = solve(p.method, g_b, m_b, self.g_n, self.m_n, s1, s2)
        P, _ = attitude_covariance(p.method, g_b, m_b, self.g_n, self.m_n, S1, S2, C)
        return C, P
