"""The initial state fix of the paper 003 filters: what the geometric solvers hand the IEKF to start from.

``tdoa_geometric`` and ``orientation_geometric`` with ``output: initialise`` emit one typed
:class:`fusion.api.Fix`, then pass every arrival through. The fix's ``value`` is ``[x y z t]``: the
position (eqs. 1-8, m) and the firing time t of the cycle's last firing (s), ``cov`` their 4 x 4 covariance;
or ``[x y z t T]`` with the firing period T (s) estimated from the agreeing cycles
(:func:`fusion_plugins.solvers.stationary_fix.period_fix`) and the 5 x 5 covariance; for the pose filter
``attitude`` is the attitude (eqs. 12-17) and ``attitude_cov`` its covariance (rad^2, navigation-frame
rotation vector).

t = a_last - |p - b_last| / c (the last arrival less its flight time), so its covariance with the position
is ``-C u / c`` and its variance ``u^T C u / c^2 + sigma_a^2`` (u the unit vector from that beacon to the
robot, C the position covariance, sigma_a the arrival noise). The ``arrival_time`` and ``direction``
models observe it (:func:`observe_initial`) as :class:`StateFix`, ``z = [p, t (, T) (, q)]``: a linear
update that, from the wide initial belief of the config, puts the filter at the fix (and combines the
estimated period with the config's prior on T). Without t the first arrival
would set t alone, and an echo there would leave the filter a few milliseconds off and every later arrival
outside its gate.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from fusion import quaternion as quat
from fusion.api import Fix, MalformedMessage, MeasurementModel, Message, Observation

__all__ = ["initial_fix", "state_fix", "period_state_fix", "observe_initial", "quaternion_covariance", "StateFix"]

NORM_VAR = 1e-6   # variance along q itself in the quaternion block of R (no physical meaning: positive definite)


def _symmetric(C: np.ndarray) -> np.ndarray:
    """C's upper triangle mirrored (what the filter uses of a covariance)."""
    C = np.asarray(C, dtype=float)
    return np.triu(C) + np.triu(C, 1).T


def state_fix(t: float, pos: np.ndarray, cov: np.ndarray, t_fire: float, cov_pt: np.ndarray, var_t: float,
              q: np.ndarray | None = None, q_sd: float | None = None, *, sensor: str = "",
              line: int | None = None, used: tuple[str, ...] = ()) -> Fix:
    """The Fix stamped at ``t`` (s) of the state ``[p, t_fire]``: position (3,) m with covariance (3, 3) m^2,
    firing time (s), their covariance ``cov_pt`` (3,) m s and ``var_t`` s^2; optionally the attitude q (4,)
    with sd ``q_sd`` per axis (rad)."""
    C = np.zeros((4, 4))
    C[:3, :3] = _symmetric(cov)
    C[:3, 3] = C[3, :3] = np.asarray(cov_pt, dtype=float)
    C[3, 3] = float(var_t)
    return _fix(t, np.r_[np.asarray(pos, dtype=float), float(t_fire)], C, q, q_sd, sensor, line, used)


def period_state_fix(t: float, pos: np.ndarray, t0: float, period: float, n_last: float, cov: np.ndarray,
                     q: np.ndarray | None = None, q_sd: float | None = None, *, sensor: str = "",
                     line: int | None = None, used: tuple[str, ...] = ()) -> Fix:
    """The Fix stamped at ``t`` (s) of the state ``[p, t_fire, T]`` from a fix of ``[p, t0, T]`` (m, s, s) with
    covariance ``cov`` (5, 5) (:func:`fusion_plugins.solvers.stationary_fix.period_fix`): the latest firing
    ``t_fire = t0 + n_last T`` and its covariance through that map; optionally the attitude as in
    :func:`state_fix`."""
    A = np.eye(5)
    A[3, 4] = float(n_last)
    C = A @ _symmetric(cov) @ A.T
    value = np.r_[np.asarray(pos, dtype=float), float(t0) + float(n_last) * float(period), float(period)]
    return _fix(t, value, 0.5 * (C + C.T), q, q_sd, sensor, line, used)


def _fix(t: float, value: np.ndarray, C: np.ndarray, q: np.ndarray | None, q_sd: float | None, sensor: str,
         line: int | None, used: tuple[str, ...]) -> Fix:
    attitude = attitude_cov = None
    if q is not None:
        attitude = quat.normalize(np.asarray(q, float))
        attitude_cov = float(q_sd) ** 2 * np.eye(3)
    return Fix(float(t), value, C, used=tuple(used), sensor=sensor, line=line, attitude=attitude,
               attitude_cov=attitude_cov)


def initial_fix(pos: np.ndarray, cov: np.ndarray, beacon: np.ndarray, arrival: float, c: float, sigma: float,
                q: np.ndarray | None = None, q_sd: float | None = None, **where: Any) -> Fix:
    """The initial fix from a position (3,) m, its covariance (3, 3), the last beacon (3,) and its arrival
    time (s, also the fix's stamp); c (m/s), sigma the arrival sd (s); optionally the attitude q (4,) and
    its sd per axis (rad). ``where``: ``sensor``, ``line``, ``used`` of the Fix."""
    d = pos - beacon
    u = d / max(float(np.linalg.norm(d)), 1e-12)
    t = arrival - float(np.linalg.norm(d)) / c
    cpt = -(cov @ u) / c
    ctt = float(u @ cov @ u) / c ** 2 + sigma ** 2
    return state_fix(arrival, pos, cov, t, cpt, ctt, q, q_sd, **where)


def quaternion_covariance(q: np.ndarray, attitude_cov: np.ndarray, norm_var: float = NORM_VAR) -> np.ndarray:
    """Covariance (4, 4) of a quaternion block for an attitude error of covariance ``attitude_cov`` (3, 3)
    (rad^2, navigation-frame rotation vector), plus ``norm_var`` along q. Isotropic errors are the same in
    the body and navigation frames (fusion_plugins.process.static_orientation.attitude_noise)."""
    from fusion_plugins.measurement.attitude import covariance_in_state
    from fusion_plugins.process.static_orientation import attitude_noise

    C = np.asarray(attitude_cov, dtype=float)
    var = C[0, 0]
    if np.array_equal(C, var * np.eye(3)):
        return attitude_noise(q, var, norm_var)
    return covariance_in_state(quat.normalize(np.asarray(q, float)), _symmetric(C), norm_var ** 0.5)


def _bad(fix: Fix, why: str) -> MalformedMessage:
    return MalformedMessage(f"an initial fix needs {why}, got value {np.asarray(fix.value).tolist()!r}")


def observe_initial(fix: Fix | Message, context) -> Observation:
    """The Observation of an initial state fix (``value`` [x y z t] with ``cov`` 4 x 4, or [x y z t T] with
    5 x 5, optionally an attitude) for a state with blocks p, t (T, q); MalformedMessage for anything else."""
    if not isinstance(fix, Fix):
        raise MalformedMessage(f"an initial fix is a solver's typed Fix, not a message of {len(fix.values)} values")
    z = np.asarray(fix.value, dtype=float)
    cov = None if fix.cov is None else np.asarray(fix.cov, dtype=float)
    if z.shape not in ((4,), (5,)) or not np.all(np.isfinite(z)):
        raise _bad(fix, "4 or 5 finite values (x y z t [T])")
    m = z.shape[0]
    if cov is None or cov.shape != (m, m) or not np.all(np.isfinite(cov)):
        raise _bad(fix, f"a finite {m} x {m} covariance")
    with_attitude = fix.attitude is not None
    R = cov
    if with_attitude:
        qv = np.asarray(fix.attitude, dtype=float)
        C = None if fix.attitude_cov is None else np.asarray(fix.attitude_cov, dtype=float)
        if qv.shape != (4,) or not np.all(np.isfinite(qv)) or not np.linalg.norm(qv) > 0:
            raise _bad(fix, "a finite, non-zero attitude quaternion")
        if C is None or C.shape != (3, 3) or not np.all(np.isfinite(C)) or not np.all(np.diag(C) > 0):
            raise MalformedMessage(f"an initial fix's attitude covariance must be 3 x 3 with a positive diagonal, "
                                   f"got {fix.attitude_cov!r}")
        q = quat.normalize(qv)
        R = np.zeros((m + 4, m + 4))
        R[:m, :m] = cov
        R[m:, m:] = quaternion_covariance(q, C)
        z = np.r_[z, q]
    lay = context.layout
    if (lay is None or "p" not in lay or "t" not in lay or (with_attitude and "q" not in lay)
            or (m == 5 and "T" not in lay)):
        raise MalformedMessage("an initial fix needs a state with blocks p and t (T for a period, q for an "
                               "attitude)")
    return Observation(fix.t, z, StateFix(context, with_attitude=with_attitude, with_period=m == 5), R)


class StateFix(MeasurementModel):
    """z = [p, t (, T) (, q)]: a direct fix of the state's position (m), firing time (s), firing period (s)
    and attitude (quaternion); the residual takes the fix's quaternion in the estimate's hemisphere (q and -q are one
    attitude). Built by :func:`observe_initial`; not a registry component."""

    name = "initial fix"
    #: the run updates with it ungated (fusion.scheduler): it replaces the config's wide prior
    initialises = True

    def __init__(self, context, with_attitude: bool, with_period: bool = False):
        super().__init__(None, context)
        lay = context.layout
        self._p = lay["p"]
        self._t = [lay["t"].start] + ([lay["T"].start] if with_period else [])   # t (and T): scalars
        self._q = lay["q"] if with_attitude else None
        self._m = 3 + len(self._t)
        self.dim = self._m + (4 if with_attitude else 0)
        idx = list(range(self._p.start, self._p.stop)) + self._t
        if with_attitude:
            idx += list(range(self._q.start, self._q.stop))
        self._H = np.zeros((self.dim, lay.n))
        self._H[np.arange(self.dim), idx] = 1.0

    def h(self, x: np.ndarray) -> np.ndarray:
        parts = [x[..., self._p], x[..., self._t]]
        if self._q is not None:
            parts.append(quat.normalize(x[..., self._q]))
        return np.concatenate(parts, axis=-1)

    def jacobian(self, x: np.ndarray) -> np.ndarray | None:
        return self._H if self._q is None else None      # the normalised quaternion: numerical

    def residual(self, z: np.ndarray, z_hat: np.ndarray) -> np.ndarray:
        r = z - z_hat
        if self._q is None:
            return r
        m = self._m
        flip = np.einsum("...i,...i->...", z[..., m:], z_hat[..., m:]) < 0
        r = np.array(r, dtype=float, copy=True)
        r[..., m:] = np.where(flip[..., None], -z[..., m:], z[..., m:]) - z_hat[..., m:]
        return r
