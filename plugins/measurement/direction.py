"""Measurement ``direction``: the closest receiver's normal as the direction of the beacon in the body frame
(paper 003 eq. 19), optionally with the pulse's arrival time (eq. 11) for one pose filter.

.. math::
    [\\alpha\\ \\beta\\ \\gamma]^T = C_b^n(q)^T \\frac{b_i - p}{|b_i - p|}

(the paper's RPY^T, here the quaternion attitude q, body-to-navigation). The measured value is the unit
normal (body frame FRD) of the receiver that heard the pulse first, one of 32 on a truncated icosahedron
(``receiver`` 1-32 of the ``arrival_time`` simulator and its header ``# receiver N: x y z``). The error is
the discretisation of direction: the truth is anywhere in the receiver's cell, up to ~21 deg from its
normal (half the 41.8 deg spacing). Modelled as white noise of sd ``sd_deg`` per tangent axis, by default
the RMS of that discretisation (:func:`discretisation_sd`: 10.2 deg per axis for this array), though in
truth the error is deterministic for a fixed attitude (the paper's caveat: a static filter grows
over-confident; the random-walk process noise keeps it honest).

``cell`` (not in the paper) adds what the closest receiver says exactly: the direction is inside that
receiver's cell, the spherical polygon where its normal n_r is the closest, i.e. ``m_C . u >= 0`` for
every other receiver C with ``m_C = unit(n_r - n_C)`` (the great circles bisecting r and its neighbours).
One more component, ``h_cell = min(0, min_C m_C . u)`` with z = 0: zero (and no information) inside the
cell, the angular distance to the violated edge outside, so a prediction outside the cell is pulled onto its
edge. Its residual is clipped (Huber) at ``cell_clip_sigma`` sd so a far prediction is pulled, not gated out.
"""
from __future__ import annotations

from functools import lru_cache
from typing import Literal

import numpy as np
from pydantic import Field

from fusion import quaternion as quat
from fusion.api import ConfigError, Fix, MalformedMessage, MeasurementModel, Message, Observation, Params

from fusion_plugins.solvers.initial_fix import observe_initial
from fusion_plugins.solvers.tdoa_geometric import parse_arrival

_FLIP = np.array([1.0, -1.0, -1.0, -1.0])


@lru_cache(maxsize=4)
def receiver_normals(kind: str) -> np.ndarray:
    """Unit normals (32, 3) (body frame FRD) of the receivers of array ``kind`` (``truncated_icosahedron``),
    receiver r at row r - 1."""
    from fusion_plugins.simulators.arrival import truncated_icosahedron_normals
    return truncated_icosahedron_normals()


def discretisation_sd(normals: np.ndarray, samples: int = 20000) -> float:
    """RMS per tangent axis (rad) of the angle between a direction and its closest normal, over directions
    spread evenly on the sphere (a Fibonacci lattice of ``samples`` points: deterministic)."""
    k = np.arange(samples) + 0.5
    z = 1.0 - 2.0 * k / samples
    phi = np.pi * (1.0 + 5 ** 0.5) * k
    s = np.sqrt(1.0 - z * z)
    d = np.c_[s * np.cos(phi), s * np.sin(phi), z]
    ang = np.arccos(np.clip((d @ normals.T).max(axis=1), -1.0, 1.0))
    return float(np.sqrt(np.mean(ang ** 2) / 2.0))


class Direction(MeasurementModel):
    """Direction of beacon i in the body frame from the closest receiver (paper 003 eq. 19): z (3,) unit
    vector (body FRD); with ``arrival: true`` z = [arrival time (s), direction (3)] (eqs. 11 and 19 in one
    update of a pose filter, state ``p T t q`` of ``firing_clock`` with ``attitude_sd_deg``); with ``cell``
    one more component, the cell constraint (module docstring), z = 0.

    The state needs the attitude block ``q``; the position comes from the block ``p`` when the state has
    one, else from ``position`` (m, a known or separately estimated position: :meth:`at` binds another).
    Messages: ``beacon arrival receiver``, or (with ``arrival: true``) the initial state fix of a geometric
    solver (a fusion.api.Fix, :mod:`fusion_plugins.solvers.initial_fix`). R is attached to each observation: ``sd_deg`` (rad^2 after
    conversion, default the receivers' discretisation) per direction component, ``arrival_sd`` (s) for the
    arrival time; a ``noise`` in the config is not used.
    """

    name = "direction"
    carries_R = True    # R from its own arrival/direction sd params

    class Params(Params):
        receivers: Literal["truncated_icosahedron"] | list[tuple[float, float, float]] = Field(
            "truncated_icosahedron", description="receiver normals (body frame), numbered from 1")
        sd_deg: float | None = Field(None, gt=0.0, description="direction sd per axis (deg; default: the RMS "
                                     "discretisation of the receivers, 10.2 for the truncated icosahedron)")
        arrival: bool = Field(False, description="also the arrival time (eq. 11): z = [t_i, direction]")
        arrival_sd: float = Field(2.0e-4, gt=0.0, description="arrival time sd (s), with arrival: true")
        speed_of_sound: float = Field(340.0, gt=0.0, description="c (m/s), with arrival: true")
        position: tuple[float, float, float] | None = Field(None, description="robot position (m) when the "
                                                             "state has no position block")
        beacons: list[str] | None = Field(None, description="beacons (default: all config beacons)")
        cell: bool = Field(False, description="also the constraint that the direction is inside the receiver's "
                           "cell: one component, min(0, min_C m_C . direction), 0 inside (not in the paper)")
        cell_sd_deg: float = Field(1.0, gt=0.0, description="sd (deg) of the cell constraint")
        cell_clip_sigma: float = Field(2.0, gt=0.0, description="the cell residual is clipped to this many of "
                                       "its sd (Huber): a prediction far outside is pulled in, not gated out")
        position_from_direction: bool = Field(False, description="let the directions update the position "
                                              "too (dh/dp in the Jacobian); False: the position estimate "
                                              "only feeds the direction model")

    def __init__(self, params=None, context=None, bound: str | None = None, position=None,
                 receiver: int | None = None):
        super().__init__(params, context)
        p, ctx = self.params, self.context
        lay = ctx.layout
        if lay is None or "q" not in lay or lay.block("q").kind != "quaternion":
            raise ConfigError("direction needs a state with an attitude quaternion block 'q' (process "
                              "static_orientation, or firing_clock with attitude_sd_deg)")
        self._q = lay["q"]
        self._p = lay["p"] if "p" in lay else None
        if self._p is not None and self._p.stop - self._p.start != 3:
            raise ConfigError("direction needs a 3-D position block 'p'")
        if p.arrival and (self._p is None or "t" not in lay):
            raise ConfigError("direction: arrival: true needs the state p T t of firing_clock")
        self._t = lay["t"].start if p.arrival else None
        self.position = (np.asarray(position, float) if position is not None
                         else np.asarray(p.position, float) if p.position is not None else None)
        if self._p is None and self.position is None:
            raise ConfigError("direction: the state has no position block 'p'; give 'position: [x, y, z]'")
        self.normals = (receiver_normals(p.receivers) if isinstance(p.receivers, str)
                        else np.asarray(p.receivers, float) / np.linalg.norm(p.receivers, axis=1, keepdims=True))
        if self.normals.ndim != 2 or self.normals.shape[1] != 3 or len(self.normals) < 4:
            raise ConfigError("direction: receivers must be at least 4 normals of 3 values")
        names = p.beacons if p.beacons is not None else list(ctx.beacons)
        bad = [b for b in names if b not in ctx.beacons or len(ctx.beacons[b]) != 3]
        if bad or not names:
            raise ConfigError(f"direction: unknown, 2-D or no beacon(s) {bad}; the config defines "
                              f"{sorted(ctx.beacons)}")
        self._known = tuple(names)
        self.sd = np.deg2rad(p.sd_deg) if p.sd_deg is not None else _default_sd(p.receivers, self.normals)
        self.receiver = receiver
        self._M = None
        if p.cell and receiver is not None:      # inward unit normals of the cell's bisecting great circles
            M = self.normals[receiver - 1] - np.delete(self.normals, receiver - 1, axis=0)
            self._M = M / np.linalg.norm(M, axis=1, keepdims=True)
        self.dim = (4 if p.arrival else 3) + (self._M is not None)
        self.R = np.diag(([p.arrival_sd ** 2] if p.arrival else []) + [self.sd ** 2] * 3
                         + ([np.deg2rad(p.cell_sd_deg) ** 2] if self._M is not None else []))
        self._clip = p.cell_clip_sigma * np.deg2rad(p.cell_sd_deg)
        self.bound = bound
        if bound is not None:
            self._b = np.asarray(ctx.beacons[bound], float)
        self._bind = lru_cache(maxsize=1024)(lambda name, receiver=None: Direction(
            self.params, self.context, name, self.position, receiver))

    def at(self, position) -> "Direction":
        """This model with the robot at ``position`` (3,) m (for a state without a position block)."""
        return Direction(self.params, self.context, self.bound, position, self.receiver)

    def _los(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = x[..., self._p] if self._p is not None else self.position
        d = self._b - p
        r = np.sqrt(np.einsum("...d,...d->...", d, d))[..., None]
        return d / np.maximum(r, 1e-12), r

    def h(self, x: np.ndarray) -> np.ndarray:
        u, r = self._los(x)
        q = x[..., self._q] * _FLIP                                 # conj(q): C_n^b
        dirs = quat.rotate(q, np.broadcast_to(u, q.shape[:-1] + (3,)))
        parts = [dirs]
        if self._t is not None:
            parts.insert(0, x[..., self._t, None] + r / self.params.speed_of_sound)
        if self._M is not None:
            parts.append(np.minimum(0.0, (dirs @ self._M.T).min(axis=-1, keepdims=True)))
        return np.concatenate(parts, axis=-1) if len(parts) > 1 else dirs

    def residual(self, z: np.ndarray, z_hat: np.ndarray) -> np.ndarray:
        """z - z_hat; the cell component clipped to +-cell_clip_sigma of its sd."""
        r = z - z_hat
        if self._M is not None:
            r = np.array(r, dtype=float, copy=True)
            r[..., -1] = np.clip(r[..., -1], -self._clip, self._clip)
        return r

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        u, r = self._los(x)
        qc = x[self._q] * _FLIP
        H = np.zeros((self.dim, x.shape[-1]))
        k = 1 if self._t is not None else 0
        H[k:k + 3, self._q] = quat.rotate_jacobian(qc, u) * _FLIP             # d(C(q*) u)/dq
        if self._p is not None and self.params.position_from_direction:
            C = quat.to_matrix(qc)
            H[k:k + 3, self._p] = -C @ (np.eye(3) - np.outer(u, u)) / max(float(r[0]), 1e-12)
        if self._M is not None:
            dirs = quat.rotate(qc, u)
            v = self._M @ dirs
            j = int(np.argmin(v))
            H[-1] = self._M[j] @ H[k:k + 3] if v[j] < 0.0 else 0.0
        if self._t is not None:
            H[0, self._p] = -u / self.params.speed_of_sound
            H[0, self._t] = 1.0
        return H

    def observe(self, message: Message | Fix) -> Observation | None:
        if isinstance(message, Fix):                                 # a geometric initialiser's state fix
            if self._t is None:
                raise MalformedMessage("direction: an initial state fix needs arrival: true (a state p T t q)")
            return observe_initial(message, self.context)
        vals = message.values
        if len(vals) != 3:
            raise MalformedMessage("direction expects 'beacon arrival receiver'")
        label, arrival = parse_arrival(message, self._known)
        rec = self._receiver(vals[2])
        n = self.normals[rec - 1]
        z = np.r_[arrival, n] if self._t is not None else n.copy()
        if not self.params.cell:
            return Observation(message.t, z, self._bind(label), self.R)
        model = self._bind(label, rec)
        return Observation(message.t, np.r_[z, 0.0], model, model.R)

    def _receiver(self, v) -> int:
        try:
            rec = float(v)
        except (TypeError, ValueError):
            raise MalformedMessage(f"receiver is not a number: {v!r}") from None
        if rec != int(rec) or not 1 <= rec <= len(self.normals):
            raise MalformedMessage(f"receiver must be 1-{len(self.normals)}, got {v!r}")
        return int(rec)


@lru_cache(maxsize=4)
def _cached_sd(kind: str) -> float:
    return discretisation_sd(receiver_normals(kind))


def _default_sd(kind, normals: np.ndarray) -> float:
    return _cached_sd(kind) if isinstance(kind, str) else discretisation_sd(normals)
