"""The initial state fix of the paper 003 filters: what the geometric solvers hand the IEKF to start from.

``tdoa_geometric`` and ``orientation_geometric`` with ``output: initialise`` emit one message, then pass
every arrival through. The message carries the position (eqs. 1-8), the firing time t of the cycle's last
firing and, for the pose filter, the attitude (eqs. 12-17), with covariances::

    x y z  cxx cxy cxz cyy cyz czz  t  cxt cyt czt ctt  [qw qx qy qz sd]      (14 or 19 values)

t = a_last - |p - b_last| / c (the last arrival less its flight time), so its covariance with the position
is ``-C u / c`` and its variance ``u^T C u / c^2 + sigma_a^2`` (u the unit vector from that beacon to the
robot, C the position covariance, sigma_a the arrival noise). The ``arrival_time`` and ``direction``
models observe it as :class:`StateFix`, ``z = [p, t (, q)]``: a linear update that, from the wide initial
belief of the config, puts the filter at the fix. Without t the first arrival would set t alone, and an
echo there would leave the filter a few milliseconds off and every later arrival outside its gate.
"""
from __future__ import annotations

import numpy as np

from fusion import quaternion as quat
from fusion.api import MalformedMessage, MeasurementModel, Message, Observation

from .ols_trilateration import pack_fix, unpack_fix

SIZES = (14, 19)


def pack_initial(pos: np.ndarray, cov: np.ndarray, beacon: np.ndarray, arrival: float, c: float,
                 sigma: float, q: np.ndarray | None = None, q_sd: float | None = None) -> tuple[float, ...]:
    """Message values of an initial fix: position (3,) m, its covariance (3, 3), the last beacon (3,) and
    its arrival time (s); c (m/s), sigma the arrival sd (s); optionally the attitude q (4,) and its sd per
    axis (rad)."""
    d = pos - beacon
    u = d / max(float(np.linalg.norm(d)), 1e-12)
    t = arrival - float(np.linalg.norm(d)) / c
    cpt = -(cov @ u) / c
    ctt = float(u @ cov @ u) / c ** 2 + sigma ** 2
    out = pack_fix(pos, cov) + (t,) + tuple(cpt.tolist()) + (ctt,)
    if q is not None:
        out += tuple(quat.normalize(np.asarray(q, float)).tolist()) + (float(q_sd),)
    return out


def observe_initial(message: Message, context) -> Observation:
    """The Observation of an initial-fix message (14 or 19 values) for a state with blocks p, t (and q)."""
    from fusion_plugins.process.static_orientation import attitude_noise

    vals = message.values
    try:
        v = np.array(vals, dtype=float)
    except (TypeError, ValueError):
        raise MalformedMessage(f"an initial fix needs {' or '.join(map(str, SIZES))} numbers, got {vals!r}") from None
    if v.size not in SIZES or not np.all(np.isfinite(v)):
        raise MalformedMessage(f"an initial fix needs {' or '.join(map(str, SIZES))} finite numbers, got {vals!r}")
    pos, cov = unpack_fix(v[:9])
    m = 4 if v.size == 14 else 8
    R = np.zeros((m, m))
    R[:3, :3] = cov
    R[:3, 3] = R[3, :3] = v[10:13]
    R[3, 3] = v[13]
    z = np.r_[pos, v[9]]
    if v.size == 19:
        q = quat.normalize(v[14:18])
        if v[18] <= 0:
            raise MalformedMessage(f"an initial fix's attitude sd must be > 0, got {v[18]}")
        R[4:, 4:] = attitude_noise(q, v[18] ** 2, 1e-6)
        z = np.r_[z, q]
    lay = context.layout
    if lay is None or "p" not in lay or "t" not in lay or (v.size == 19 and "q" not in lay):
        raise MalformedMessage("an initial fix needs a state with blocks p and t (and q for an attitude)")
    return Observation(message.t, z, StateFix(context, with_attitude=v.size == 19), R)


class StateFix(MeasurementModel):
    """z = [p, t] or [p, t, q]: a direct fix of the state's position (m), firing time (s) and attitude
    (quaternion); the residual takes the fix's quaternion in the estimate's hemisphere (q and -q are one
    attitude). Built by :func:`observe_initial`; not a registry component."""

    name = "initial fix"

    def __init__(self, context, with_attitude: bool):
        super().__init__(None, context)
        lay = context.layout
        self._p, self._t = lay["p"], lay["t"].start
        self._q = lay["q"] if with_attitude else None
        self.dim = 8 if with_attitude else 4
        idx = list(range(self._p.start, self._p.stop)) + [self._t]
        if with_attitude:
            idx += list(range(self._q.start, self._q.stop))
        self._H = np.zeros((self.dim, lay.n))
        self._H[np.arange(self.dim), idx] = 1.0

    def h(self, x: np.ndarray) -> np.ndarray:
        parts = [x[..., self._p], x[..., self._t, None]]
        if self._q is not None:
            parts.append(quat.normalize(x[..., self._q]))
        return np.concatenate(parts, axis=-1)

    def jacobian(self, x: np.ndarray) -> np.ndarray | None:
        return self._H if self._q is None else None      # the normalised quaternion: numerical

    def residual(self, z: np.ndarray, z_hat: np.ndarray) -> np.ndarray:
        r = z - z_hat
        if self._q is None:
            return r
        flip = np.einsum("...i,...i->...", z[..., 4:], z_hat[..., 4:]) < 0
        r = np.array(r, dtype=float, copy=True)
        r[..., 4:] = np.where(flip[..., None], -z[..., 4:], z[..., 4:]) - z_hat[..., 4:]
        return r
