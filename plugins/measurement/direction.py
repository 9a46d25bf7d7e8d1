"""Measurement ``direction``: the closest receiver's normal as the direction of the beacon in the body frame
(paper 003 eq. 19), optionally with the pulse's arrival time (eq. 11) for one pose filter.

.. math::
    [\\alpha\\ \\beta\\ \\gamma]^T = C_b^n(q)^T \\frac{b_i - p}{|b_i - p|}

(the paper's RPY^T, here the quaternion attitude q, body-to-navigation). The measured value is the unit
normal (body frame FRD) of the receiver that heard the pulse first, receiver r of the array ``receivers``
(the config's, else the recording header's ``# receiver N: x y z`` lines: receiver_array; the paper's is
32 receivers on a truncated icosahedron). The error is
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

``error_state`` (not in the paper) models the discretisation error as state instead of white noise: the
direction components become the two tangent-plane coordinates at the receiver's normal n_r (basis
:func:`tangent_basis`, rows t1 t2 orthonormal and normal to n_r), z = [0, 0] and

.. math::
    h = T_r\\, (C_b^n(q)^T u + e_{b, c(r)})

(n_r = u + e: the normal is the true direction plus its discretisation error). ``e_{b,c}`` (rad, 3, body
frame) is the slot c of the beacon's block ``dir_err_<b>`` of the ``firing_clock`` process (a Gauss-Markov
process, optionally coupled to the attitude noise and reset on entering a new cell of its colour: that
module's docstring), c(r) the colour of receiver r in a proper colouring of the cells
(:func:`receiver_colours`): adjacent cells get different slots, so crossing a cell edge moves to another
slot and crossing back finds the error that cell left. ``sd_deg`` is then the white part only (what one
pulse adds afresh). Measured on the paper-003 walk (experiments/pose_blocks.py): not better than
the white model of the shipped config; see configs/ultrasonic_3d_pose.yaml.
"""
from __future__ import annotations

from functools import lru_cache
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


def tangent_basis(normals: np.ndarray) -> np.ndarray:
    """Orthonormal tangent bases (k, 2, 3) of unit normals (k, 3): rows t1, t2 with t1 x t2 = n
    (t1 from the axis least aligned with n; deterministic)."""
    n = np.asarray(normals, float)
    axis = np.eye(3)[np.argmin(np.abs(n), axis=1)]
    t1 = np.cross(n, axis)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    return np.stack([t1, t2], axis=1)


def adjacent_receivers(normals: np.ndarray, samples: int = 20000, tie_deg: float = 1.0) -> np.ndarray:
    """Adjacency (k, k) bool of the receivers' cells: r and s share an edge when some direction of a
    Fibonacci lattice of ``samples`` points has them as its two closest normals within ``tie_deg``
    (deterministic)."""
    k = np.arange(samples) + 0.5
    z = 1.0 - 2.0 * k / samples
    phi = np.pi * (1.0 + 5 ** 0.5) * k
    s = np.sqrt(1.0 - z * z)
    d = np.c_[s * np.cos(phi), s * np.sin(phi), z]
    ang = np.arccos(np.clip(d @ np.asarray(normals, float).T, -1.0, 1.0))
    order = np.argsort(ang, axis=1)[:, :2]
    a = np.take_along_axis(ang, order, axis=1)
    tie = a[:, 1] - a[:, 0] < np.deg2rad(tie_deg)
    adj = np.zeros((len(normals), len(normals)), bool)
    adj[order[tie, 0], order[tie, 1]] = True
    return adj | adj.T


def receiver_colours(normals: np.ndarray) -> np.ndarray:
    """Colour (k,) int >= 0 of each receiver, a proper colouring of the cells (adjacent cells differ):
    greedy in the order of most neighbours first (ties by index; deterministic). 4 colours for the
    truncated icosahedron, as paper 003 sec. 3 colours its receivers."""
    adj = adjacent_receivers(normals)
    colour = np.full(len(normals), -1)
    for r in sorted(range(len(normals)), key=lambda i: (-int(adj[i].sum()), i)):
        used = set(colour[adj[r]].tolist())
        colour[r] = next(c for c in range(len(normals)) if c not in used)
    return colour


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
        receivers: str | list[tuple[float, float, float]] | None = Field(
            None, description="receiver normals (body frame FRD), numbered from 1: a list, the name of an array "
            "(truncated_icosahedron: the paper's, in the arrival_time simulator's numbering) or a file "
            "(receiver_array); none: the recording header's '# receiver N: x y z' lines")
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
        error_state: bool = Field(False, description="the discretisation error as state (module docstring): "
                                  "needs the firing_clock blocks dir_err_<beacon>; the direction is then 2 "
                                  "tangent components (rad) and sd_deg their white part")

    def __init__(self, params=None, context=None, bound: str | None = None, position=None,
                 receiver: int | None = None, normals: tuple[np.ndarray, dict] | None = None):
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
        if normals is None:
            from fusion_plugins.measurement.receiver_array import resolve_receivers

            normals = resolve_receivers(p.receivers, ctx, "direction")
        self.normals, self._receivers_info = normals
        key = tuple(map(tuple, self.normals))
        names = p.beacons if p.beacons is not None else list(ctx.beacons)
        bad = [b for b in names if b not in ctx.beacons or len(ctx.beacons[b]) != 3]
        if bad or not names:
            raise ConfigError(f"direction: unknown, 2-D or no beacon(s) {bad}; the config defines "
                              f"{sorted(ctx.beacons)}")
        self._known = tuple(names)
        if p.error_state and p.sd_deg is None:
            raise ConfigError("direction: error_state: true needs sd_deg, the white part of the direction's error "
                              "(deg per tangent axis; the discretisation itself is the state)")
        self.sd = np.deg2rad(p.sd_deg) if p.sd_deg is not None else _cached_sd(key)
        self.receiver = receiver
        self._M = None
        if p.cell and receiver is not None:      # inward unit normals of the cell's bisecting great circles
            M = self.normals[receiver - 1] - np.delete(self.normals, receiver - 1, axis=0)
            self._M = M / np.linalg.norm(M, axis=1, keepdims=True)
        self._e = self._Tr = None
        if p.error_state:
            colours = _colours(key)
            need = 3 * (int(colours.max()) + 1)
            for b in names:
                blk = f"dir_err_{b}"
                if blk not in lay or lay[blk].stop - lay[blk].start < need:
                    raise ConfigError(f"direction: error_state: true needs the state block {blk!r} of at least "
                                      f"{need} elements ({need // 3} receiver colours x 3 axes): firing_clock with "
                                      f"direction_error_sd_deg and direction_error_slots >= {need // 3}")
            if receiver is not None and bound is not None:
                start = lay[f"dir_err_{bound}"].start + 3 * int(colours[receiver - 1])
                self._e = slice(start, start + 3)
                self._Tr = tangent_basis(self.normals[receiver - 1][None])[0]
        ndir = 2 if p.error_state else 3
        self.dim = (1 if p.arrival else 0) + ndir + (self._M is not None)
        self.R = np.diag(([p.arrival_sd ** 2] if p.arrival else []) + [self.sd ** 2] * ndir
                         + ([np.deg2rad(p.cell_sd_deg) ** 2] if self._M is not None else []))
        self._clip = p.cell_clip_sigma * np.deg2rad(p.cell_sd_deg)
        self.bound = bound
        if bound is not None:
            self._b = np.asarray(ctx.beacons[bound], float)
        self._bind = lru_cache(maxsize=1024)(lambda name, receiver=None: Direction(
            self.params, self.context, name, self.position, receiver, normals))

    def at(self, position) -> "Direction":
        """This model with the robot at ``position`` (3,) m (for a state without a position block)."""
        return Direction(self.params, self.context, self.bound, position, self.receiver,
                         (self.normals, self._receivers_info))

    def info(self) -> dict:
        """The summary's ``info`` (fusion.api.ReportsInfo): the receiver array used and where it came from."""
        return {"receiver_array": dict(self._receivers_info)}

    def _los(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = x[..., self._p] if self._p is not None else self.position
        d = self._b - p
        r = np.sqrt(np.einsum("...d,...d->...", d, d))[..., None]
        return d / np.maximum(r, 1e-12), r

    def h(self, x: np.ndarray) -> np.ndarray:
        u, r = self._los(x)
        q = x[..., self._q] * _FLIP                                 # conj(q): C_n^b
        dirs = quat.rotate(q, np.broadcast_to(u, q.shape[:-1] + (3,)))
        parts = [dirs if self._e is None else (dirs + x[..., self._e]) @ self._Tr.T]
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
        n = x.shape[-1]
        H = np.zeros((self.dim, n))
        k = 1 if self._t is not None else 0
        J = np.zeros((3, n))                                                    # d(C(q*) u)/dx
        J[:, self._q] = quat.rotate_jacobian(qc, u) * _FLIP
        if self._p is not None and self.params.position_from_direction:
            C = quat.to_matrix(qc)
            J[:, self._p] = -C @ (np.eye(3) - np.outer(u, u)) / max(float(r[0]), 1e-12)
        if self._e is None:
            H[k:k + 3] = J
        else:                                                                   # tangent coordinates + error
            H[k:k + 2] = self._Tr @ J
            H[k:k + 2, self._e] = self._Tr
        if self._M is not None:
            dirs = quat.rotate(qc, u)
            v = self._M @ dirs
            j = int(np.argmin(v))
            H[-1] = self._M[j] @ J if v[j] < 0.0 else 0.0
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
        n = self.normals[rec - 1] if not self.params.error_state else np.zeros(2)
        z = np.r_[arrival, n] if self._t is not None else n.copy()
        if not (self.params.cell or self.params.error_state):
            return Observation(message.t, z, self._bind(label), self.R)
        model = self._bind(label, rec)
        return Observation(message.t, np.r_[z, 0.0] if self.params.cell else z, model, model.R)

    def _receiver(self, v) -> int:
        try:
            rec = float(v)
        except (TypeError, ValueError):
            raise MalformedMessage(f"receiver is not a number: {v!r}") from None
        if rec != int(rec) or not 1 <= rec <= len(self.normals):
            raise MalformedMessage(f"receiver must be 1-{len(self.normals)}, got {v!r}")
        return int(rec)


def receiver_cells(receivers) -> tuple[np.ndarray, np.ndarray]:
    """(normals (k, 3) unit, colours (k,)) of ``receivers`` (an array kind, or a list of normals)."""
    key = receivers if isinstance(receivers, str) else tuple(map(tuple, receivers))
    colours = _colours(key)
    normals = receiver_normals(key) if isinstance(key, str) else np.asarray(key, float)
    return normals / np.linalg.norm(normals, axis=1, keepdims=True), colours


@lru_cache(maxsize=8)
def _colours(receivers) -> np.ndarray:
    """receiver_colours of ``receivers`` (an array kind, or a tuple of normals), cached."""
    normals = receiver_normals(receivers) if isinstance(receivers, str) else np.asarray(receivers, float)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    return receiver_colours(normals)


@lru_cache(maxsize=8)
def _cached_sd(receivers) -> float:
    """discretisation_sd of ``receivers`` (an array kind, or a tuple of unit normals), cached."""
    normals = receiver_normals(receivers) if isinstance(receivers, str) else np.asarray(receivers, float)
    return discretisation_sd(normals)
