"""Process ``firing_clock``: position random walk (or constant velocity) and the beacons' firing clock
(paper 003 eqs. 9-10).

State ``p:3 T:1 t:1``: the robot position (m, the beacons' frame), the inter-firing period T (s) and the
time t (s, receiver clock) of the latest beacon firing. One step is one firing (eq. 10)::

    x(n+1) = Phi x(n) + w(n+1),   Phi = I except Phi[t, T] = 1  (t advances by T)
    w = [w_x w_y w_z w_T 0],      Q = diag(sd_x^2, sd_y^2, sd_z^2, sd_T^2, sd_t^2)   (sd_t = 0: the paper)

The scheduler predicts over elapsed time: between two arrivals dt = T + (d_j - d_i) / c, so the number of
firings in between is ``n = round(dt / T)`` (1 normally, 2 after a missed pulse, 0 for the first update).
That holds while the largest difference of beacon distances is below c T / 2 (38 m at 340 m/s, 225 ms).
Over n firings the transition is Phi^n (t advances by n T) and the noise the sum of n steps:

    Q_n[p] = n Q_p,  Q_n[T, T] = n q_T,  Q_n[t, T] = q_T n (n - 1) / 2,
    Q_n[t, t] = q_T (n - 1) n (2n - 1) / 6 + n q_t

What the random walk covers: ``position_sd`` is the sd of an independent zero-mean step per firing, so
the model expects the robot to wander, not to go somewhere. The paper (sec. 4.2) chooses it "of the same
order as the maximum movement anticipated in each axis in one time step", but it is not a bound: a robot
moving steadily at v m/s moves v T every firing in the same direction, and a random-walk filter follows a
ramp with a steady lag of v T over its gain per firing, many steps' worth at the small gains of a noisy
arrival time (e.g. 2 cm/s with 5 mm: 316 mm RMSE, NEES 56 on 3 dof, and the echo gate then rejects
~1/3 of the genuine arrivals of the lagging filter as echoes). Raising position_sd covers steady motion
at a price when the robot stands still (27 -> 91 mm RMSE at 0.05 m): one per-step sd cannot serve both. The
attitude walk (``attitude_sd_deg``) is the same: it covers an attitude that jitters, not one that turns steadily.

``motion: constant_velocity`` (not in the paper; the random walk stays the default) adds the velocity
``v:3`` (m/s, the beacons' frame) after ``t`` and before the attitude, the standard PV model of white
acceleration of spectral density q_a (``acceleration_psd``, m^2/s^3 per axis) over the elapsed time dt
(s, between the arrivals, not n T: the position is the one at the arrival)::

    p(k+1) = p + v dt,   v(k+1) = v
    Q[p, p] = q_a dt^3 / 3 + n sd_p^2,   Q[p, v] = q_a dt^2 / 2,   Q[v, v] = q_a dt

(``position_sd`` still adds its random walk per firing: 0 for the plain PV model.) It follows steady
motion without lag; q_a sets how fast the velocity may change: over a time tau the velocity's sd grows by
sqrt(q_a tau), so 1e-4 m^2/s^3 is ~1 cm/s in 1 s.

With ``attitude_sd_deg`` the state gains the attitude ``q:4`` (quaternion, body-to-navigation), held
constant up to a random walk of that many degrees per firing about each body axis (the process of
``static_orientation``, sec. 5.2): one pose filter for position and orientation (``direction`` with
``arrival: true`` measures both from each pulse).

With ``direction_error_sd_deg`` (and the attitude) the state also gains, per beacon b, a block
``dir_err_<b>`` of ``3 * direction_error_slots`` elements: the discretisation error ``e = n_r - u`` of b's
measured direction (rad, body frame FRD: the receiver's normal n_r less the true direction u) in each of
``direction_error_slots`` slots, one slot per colour of a proper colouring of the receiver cells
(``direction`` with ``error_state: true`` picks the slot of the receiver that heard the pulse: adjacent
cells never share one). Each slot is a first-order Gauss-Markov process over the elapsed time dt (s)::

    e(k+1) = a e(k) + w,   a = exp(-dt / tau),   Cov e = sd^2 (stationary, per axis)

sd: the discretisation's RMS per tangent axis; tau: the time the error of a direction inside one cell takes
to decorrelate. ``direction_error_coupling``: ``direction`` (default) says what the error's increments are:
inside a cell the normal n_r stays while u moves, so ``e`` moves by minus the direction's own motion,
``w = -du + w_0`` with ``du = [u]x dtheta - (I - u u^T) C^T dp / r`` from the attitude noise dtheta
(body-frame rotation) and the position noise dp of the same step (u = C^T (b - p) / r, r = |b - p|,
evaluated at the mean), and ``w_0`` independent noise for the rest of ``sd^2 (1 - a^2)`` (0 when tau is
2 sd^2 over the direction's variance rate, the principle; the decay a stands in for the cell's bound).
Then z = n_r stays put in a cell in the model as in truth, and carries no information on the attitude's
motion there. ``none``: w independent of the state's noise, Cov w = sd^2 (1 - a^2) I. A slot resets
(``direction_error_reset``: mean 0, variance sd^2, no correlation) when the beacon's direction enters a
cell of the slot's colour other than the one the slot holds (the colour-c normal closest to u + e_c).
Measured on the paper-003 walk (experiments/pose_blocks.py): not better than the shipped
config's white model, which does not use it.
"""
from __future__ import annotations

import numpy as np
from pydantic import Field, field_validator, model_validator

from typing import Literal

from fusion import quaternion as quat
from fusion.api import Block, ConfigError, Params, ProcessModel, StateLayout

from .static_orientation import attitude_noise


def _skew(v: np.ndarray) -> np.ndarray:
    """[v]x (..., 3, 3) of vectors v (..., 3): [v]x a = v x a."""
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1), np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


class DirectionErrorBlock(Block):
    """A vector block of a beacon's direction-error slots, elements ``<name>_0 .. <name>_<size-1>`` (slot k,
    body axis a at element 3 k + a)."""

    def element_names(self) -> tuple[str, ...]:
        return tuple(f"{self.name}_{i}" for i in range(self.size))


def direction_error_block(beacon: str) -> str:
    """Name of the state block of ``beacon``'s direction-discretisation error (``dir_err_<beacon>``)."""
    return f"dir_err_{beacon}"


class FiringClock(ProcessModel):
    """Position random walk + firing clock of paper 003 (eq. 10); state ``p:3 T:1 t:1`` (m, s, s), then
    ``v:3`` (m/s) with ``motion: constant_velocity``, then the attitude ``q:4`` with ``attitude_sd_deg``.

    Params: ``position_sd``: random-walk sd per firing (m, one value or one per axis; the paper: "of the
    same order as the maximum movement anticipated in each axis in one time step", but a walk's sd is not a
    bound on the move: it covers a robot that wanders, not one that goes somewhere, module docstring);
    ``motion`` and ``acceleration_psd`` (m^2/s^3): the constant-velocity option; ``period_sd``: drift of T per firing
    (s; temperature of the beacon electronics, the receiver's time base); ``clock_sd``: jitter of the firing
    time itself per firing (s; 0 in the paper); with the attitude, ``direction_error_sd_deg`` (deg),
    ``direction_error_tau_s`` (s), ``direction_error_slots`` and ``direction_error_beacons``: the blocks
    ``dir_err_<beacon>`` of the directions' discretisation error (module docstring)."""

    name = "firing_clock"

    class Params(Params):
        position_sd: float | list[float] = Field(0.005, description="m per firing, per axis (1 or 3 values): the "
                                                 "sd of a random walk, not a bound on the move (class docstring)")
        motion: Literal["random_walk", "constant_velocity"] = Field(
            "random_walk", description="random_walk: the paper's eq. 10; constant_velocity: adds the velocity "
            "v:3 (m/s) driven by white acceleration of density acceleration_psd (module docstring)")
        acceleration_psd: float | list[float] = Field(1.0e-4, description="with constant_velocity: spectral "
                                                      "density of the white acceleration, m^2/s^3 per axis (1 "
                                                      "or 3 values)")
        period_sd: float = Field(1e-7, ge=0.0, description="s per firing: drift of the period T")
        clock_sd: float = Field(0.0, ge=0.0, description="s per firing: noise on the firing time t (paper: 0)")
        attitude_sd_deg: float | None = Field(None, ge=0.0, description="add the attitude q:4 with a random "
                                              "walk of this many deg per firing about each axis (None: no "
                                              "attitude)")
        norm_sd: float = Field(1e-3, gt=0.0, description="with attitude: sd along q itself per firing")
        direction_error_sd_deg: float | None = Field(None, gt=0.0, le=90.0, description="with attitude: add "
                                                     "per beacon the Gauss-Markov discretisation error of its "
                                                     "measured direction, stationary sd (deg per tangent axis; "
                                                     "None: no error state)")
        direction_error_tau_s: float = Field(130.0, gt=0.0, le=1e9, description="correlation time (s) of "
                                             "the direction error (module docstring)")
        direction_error_slots: int = Field(4, ge=1, le=64, description="slots per beacon: the colours of the "
                                           "receiver cells (4 for the truncated icosahedron, paper 003 "
                                           "sec. 3)")
        direction_error_beacons: list[str] | None = Field(None, description="beacons with an error block "
                                                          "(default: all config beacons)")
        direction_error_receivers: Literal["truncated_icosahedron"] | list[tuple[float, float, float]] = Field(
            "truncated_icosahedron", description="the receiver normals (body frame), as the direction model's "
            "receivers: their cells and colours decide the resets")
        direction_error_reset: bool = Field(True, description="reset a slot (mean 0, variance sd^2, no "
                                            "correlation) when the beacon's predicted direction enters a cell "
                                            "of the slot's colour other than the one the slot holds")
        direction_error_coupling: Literal["direction", "direction_position", "none"] = Field(
            "direction", description="direction: the error's increments are minus the direction's own (from "
            "the attitude and position noise); none: independent of them (module docstring)")

        @field_validator("position_sd", "acceleration_psd")
        @classmethod
        def _three(cls, v, info):
            s = np.atleast_1d(np.asarray(v, float))
            if s.size not in (1, 3) or np.any(s < 0) or not np.all(np.isfinite(s)):
                raise ValueError(f"{info.field_name} needs 1 or 3 finite values >= 0, got {v}")
            return v

        @model_validator(mode="after")
        def _psd_needs_velocity(self):
            if "acceleration_psd" in self.model_fields_set and self.motion != "constant_velocity":
                raise ValueError("acceleration_psd is the noise of motion: constant_velocity (the random walk's "
                                 "is position_sd); set motion: constant_velocity or drop it")
            return self

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        p = self.params
        blocks = [Block("p", 3), Block("T", 1), Block("t", 1)]
        self.velocity = p.motion == "constant_velocity"
        if self.velocity:
            blocks.append(Block("v", 3))
        self._iq = slice(5 + 3 * self.velocity, 9 + 3 * self.velocity)     # the attitude q, when there is one
        self.attitude = p.attitude_sd_deg is not None
        if self.attitude:
            blocks.append(Block("q", 4, "quaternion"))
            self._qa = np.deg2rad(p.attitude_sd_deg) ** 2
        self._ge = None                        # slice of the direction-error blocks (all beacons, contiguous)
        if p.direction_error_sd_deg is not None:
            if not self.attitude:
                raise ConfigError("firing_clock: direction_error_sd_deg needs attitude_sd_deg (the pose state)")
            names = (p.direction_error_beacons if p.direction_error_beacons is not None
                     else list(self.context.beacons))
            bad = [b for b in names if b not in self.context.beacons]
            if bad or not names or len(set(names)) != len(names):
                raise ConfigError(f"firing_clock: direction_error_beacons {names} must be distinct beacons of the "
                                  f"config ({sorted(self.context.beacons)})")
            start = sum(b.size for b in blocks)
            blocks += [DirectionErrorBlock(direction_error_block(b), 3 * p.direction_error_slots) for b in names]
            self._ge = slice(start, start + 3 * p.direction_error_slots * len(names))
            self._evar = np.deg2rad(p.direction_error_sd_deg) ** 2
            self._eb = np.array([self.context.beacons[b] for b in names], float)    # (k, 3) m
            if self._eb.shape[1] != 3:
                raise ConfigError("firing_clock: direction errors need 3-D beacons")
            from fusion_plugins.measurement.direction import receiver_cells
            self._normals, self._colour = receiver_cells(p.direction_error_receivers)
            if int(self._colour.max()) + 1 > p.direction_error_slots:
                raise ConfigError(f"firing_clock: the receivers need {int(self._colour.max()) + 1} colours, "
                                  f"direction_error_slots is {p.direction_error_slots}")
            # per slot c: the normals of colour c (others masked), to find the cell a slot holds
            self._of_colour = np.stack([self._colour == c for c in range(p.direction_error_slots)])
        self.layout = StateLayout(blocks)
        self.n = self.layout.n
        self._qp = np.broadcast_to(np.asarray(p.position_sd, float) ** 2, (3,)).copy()
        self._qT = p.period_sd ** 2
        self._qt = p.clock_sd ** 2
        self._qv = np.broadcast_to(np.asarray(p.acceleration_psd, float), (3,)).copy()    # m^2/s^3

    @staticmethod
    def firings(x: np.ndarray, dt: float) -> np.ndarray:
        """Firings n (...,) between two arrivals dt s apart for states x (..., 5): round(dt / T), >= 0."""
        T = np.maximum(np.asarray(x, float)[..., 3], 1e-9)
        return np.maximum(np.rint(dt / T), 0.0)

    def f(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        out = np.array(x, dtype=float, copy=True)
        out[..., 4] += self.firings(x, dt) * out[..., 3]
        if self.velocity:
            out[..., 0:3] += out[..., 5:8] * max(dt, 0.0)
        if self._ge is not None:
            e = out[..., self._ge] * self._decay(dt)
            if self.params.direction_error_reset:
                keep = ~self._resets(np.asarray(x, float))                       # (..., k, slots)
                e = e * np.repeat(keep.reshape(keep.shape[:-2] + (-1,)), 3, axis=-1)
            out[..., self._ge] = e
        return out

    def _directions(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Body-frame unit directions u (..., k, 3) of the error beacons, their ranges r (..., k) (m) and
        C_b^n (..., 3, 3), for states x (..., n)."""
        qn = quat.normalize(x[..., self._iq])
        C = quat.to_matrix(qn)
        w = self._eb - x[..., None, :3]
        r = np.maximum(np.linalg.norm(w, axis=-1), 1e-9)
        u = np.einsum("...kd,...de->...ke", w / r[..., None], C)
        return u, r, C

    def _resets(self, x: np.ndarray) -> np.ndarray:
        """Which slots reset (..., k, slots) bool at states x (..., n): the beacon's direction u is in cell r*
        (closest normal) of colour c, and slot c holds another cell, the colour-c normal closest to u + e_c
        (what the slot's last measurements pinned: z = n = u + e). Adjacent cells have other colours, so
        going back and forth over an edge keeps both cells' errors; a new cell of a colour starts afresh."""
        slots = self.params.direction_error_slots
        u = self._directions(x)[0]                                               # (..., k, 3)
        e = x[..., self._ge].reshape(x.shape[:-1] + (len(self._eb), slots, 3))
        here = np.argmax(u @ self._normals.T, axis=-1)                           # (..., k)
        score = (u[..., None, :] + e) @ self._normals.T                          # (..., k, slots, 32)
        held = np.argmax(np.where(self._of_colour, score, -np.inf), axis=-1)     # (..., k, slots)
        mine = self._colour[here][..., None] == np.arange(slots)                 # (..., k, slots)
        return mine & (held != here[..., None])

    def _decay(self, dt: float) -> float:
        """exp(-dt / tau): the direction errors' mean factor over dt (s)."""
        return float(np.exp(-max(dt, 0.0) / self.params.direction_error_tau_s))

    def jacobian(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        F = np.eye(self.n)
        F[4, 3] = float(self.firings(x, dt))      # Phi^n (n held: T moves n only at a rounding boundary)
        if self.velocity:
            F[0:3, 5:8] = max(dt, 0.0) * np.eye(3)
        if self._ge is not None:
            i = np.arange(self._ge.start, self._ge.stop)
            F[i, i] = self._decay(dt)
            if self.params.direction_error_reset:
                F[i, i] *= np.repeat(~self._resets(np.asarray(x, float)).ravel(), 3)
        return F

    def Q(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        n = float(self.firings(x, dt))
        Q = np.zeros((self.n, self.n))
        Q[0, 0], Q[1, 1], Q[2, 2] = n * self._qp
        Q[3, 3] = n * self._qT
        Q[3, 4] = Q[4, 3] = self._qT * n * (n - 1) / 2
        Q[4, 4] = self._qT * (n - 1) * n * (2 * n - 1) / 6 + n * self._qt
        if self.velocity:                          # white acceleration over dt: the PV discretisation
            h = max(dt, 0.0)
            i, j = np.arange(3), np.arange(5, 8)
            Q[i, i] += self._qv * h ** 3 / 3
            Q[i, j] = Q[j, i] = self._qv * h ** 2 / 2
            Q[j, j] = self._qv * h
        if self.attitude:
            iq = self._iq
            Q[iq, iq] = attitude_noise(np.asarray(x, float)[iq], n * self._qa, n * self.params.norm_sd ** 2)
        if self._ge is not None:
            self._error_noise(Q, np.asarray(x, float), n, dt)
        return Q

    def _error_noise(self, Q: np.ndarray, x: np.ndarray, n: float, dt: float) -> None:
        """The direction errors' rows of Q (in place; module docstring), n firings over dt (s)."""
        p = self.params
        ge, k = self._ge, len(self._eb)
        slots = p.direction_error_slots
        full = self._evar * -np.expm1(-2.0 * max(dt, 0.0) / p.direction_error_tau_s)   # sd^2 (1 - a^2)
        if p.direction_error_coupling == "none":
            i = np.arange(ge.start, ge.stop)
            Q[i, i] = full
            if p.direction_error_reset:
                Q[i, i] = np.where(np.repeat(self._resets(x).ravel(), 3), self._evar, full)
            return
        qn = quat.normalize(x[self._iq])
        u, r, C = self._directions(x)                            # (k, 3) body-frame directions, (k,) m
        reset = (self._resets(x).ravel() if p.direction_error_reset
                 else np.zeros(k * slots, bool))                 # (k slots,)
        Sa = n * self._qa                                        # rad^2 per body axis
        Sp = n * self._qp                                        # m^2 per axis (3,)
        # e's noise per beacon: -du = Ga dtheta + Gp dp; Ga = -[u]x, Gp = (I - u u^T) C^T / r
        Ga = -_skew(u)                                           # (k, 3, 3)
        Gp = (np.eye(3) - u[:, :, None] * u[:, None, :]) @ C.T / r[:, None, None]
        Xi = 0.5 * quat.xi(qn)                                   # dq = Xi dtheta
        live = np.repeat(~reset, 3)[:, None]                     # a reset slot is drawn afresh: no coupling
        Gall_a = np.repeat(Ga, slots, axis=0).reshape(-1, 3) * live   # (3 k slots, 3)
        Gall_p = np.repeat(Gp, slots, axis=0).reshape(-1, 3) * live
        Q[ge, ge] = Sa * Gall_a @ Gall_a.T
        Q[ge, self._iq] = Sa * Gall_a @ Xi.T
        Q[self._iq, ge] = Q[ge, self._iq].T
        if p.direction_error_coupling == "direction_position":
            Q[ge, ge] += (Gall_p * Sp) @ Gall_p.T
            Q[ge, 0:3] = Gall_p * Sp
            Q[0:3, ge] = Q[ge, 0:3].T
        # the rest of sd^2 (1 - a^2) per tangent axis, independent (w_0)
        own = Sa + (float(np.mean(Sp)) / r ** 2 if p.direction_error_coupling == "direction_position" else 0.0 * r)
        rest = np.maximum(full - own, 0.0)
        tang = rest[:, None, None] * (np.eye(3) - u[:, :, None] * u[:, None, :]) + 1e-12 * np.eye(3)
        for b in range(k):
            for c in range(slots):
                j = ge.start + 3 * (b * slots + c)
                Q[j:j + 3, j:j + 3] += self._evar * np.eye(3) if reset[b * slots + c] else tang[b]

    # normalize: ProcessModel's (the layout's unit quaternion block q, when there is one)
