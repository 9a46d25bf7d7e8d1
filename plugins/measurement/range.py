"""Measurement ``range``: distances to named beacons, paper 001 eq. 6.

A message is ``beacon range`` (one range), or several pairs ``B1 r1 B2 r2 ...`` (in a recording, a
``# fields uwb beacon range ...`` header names the repeating pair); the model binds to the beacons a message
names. With a 2-D state and 3-D beacons the tag is at the fixed height ``tag_z``:

.. math::
    d_i = \\sqrt{(p_x - b_{i,x})^2 + (p_y - b_{i,y})^2 [+ (p_z - b_{i,z})^2 \\text{ or } (z_{tag} - b_{i,z})^2]}

Per-beacon calibration (``calibration: {B1: {bias: 0.12, scale: 1.003}}``) models what a beacon's ranging
measures for a true distance ``d_i``: ``r_i = scale_i d_i + bias_i`` (m; defaults 1 and 0). A tag mounted
away from the body origin (``lever_arm``, m, body FRD; needs the attitude block ``q``) ranges from
``p + C_b^n(q) l`` instead of ``p``.

Geometry check (paper 001's "non-optimal" layout, docs/results/uwb.md): ``geometry(x, P)`` gives the GDOP of
the sensor's beacons at the estimated position and, when the beacons are degenerate (all on one line in
2-D, or in one plane in 3-D), how many standard deviations of the belief separate the estimate from that
line or plane; across it, the mirror image of the position fits every range exactly. ``check(belief)``
turns these into ``warning`` Events (thresholds ``gdop_warn`` and ``mirror_warn_sigma``).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from pydantic import Field

from fusion.api import (MAX_MAGNITUDE, Belief, ConfigError, Event, MalformedMessage, MeasurementModel, Message,
                        Observation, Params)
from fusion.quaternion import rotate, rotate_jacobian


class BeaconCalibration(Params):
    """Range calibration of one beacon: measured = ``scale`` x true distance + ``bias``."""

    bias: float = Field(0.0, description="m, added to the scaled distance")
    scale: float = Field(1.0, gt=0.0, description="dimensionless, multiplies the true distance")


class RangeModel(MeasurementModel):
    """Ranges (m) from the position block ``p`` (2-D or 3-D) to named beacons (config ``beacons:``).

    Params: ``beacons``: the beacons this sensor may range to (default: all); ``tag_z``: the tag's height
    (m, same frame as the beacons) used when the state is 2-D and the beacons are 3-D; ``calibration``:
    per-beacon ``bias`` (m) and ``scale`` (measured = scale x distance + bias); ``lever_arm``: the tag's
    position in the body frame (m, FRD; needs the attitude block ``q``); ``max_range``: the sensor's longest
    range (m), a longer one is malformed; ``gdop_warn`` and
    ``mirror_warn_sigma``: thresholds of ``check`` (see the module docstring)."""

    name = "range"
    fields = ("beacon", "range")
    dim = 1
    carries_R = False   # a range message has no covariance: R is the sensor's noise

    class Params(Params):
        beacons: list[str] | None = None
        tag_z: float = 0.0
        calibration: dict[str, BeaconCalibration] = Field(default_factory=dict, description="per beacon: bias "
                                                          "(m) and scale; measured = scale x distance + bias")
        lever_arm: list[float] | None = Field(None, min_length=3, max_length=3, description="m, body FRD: the "
                                              "tag's offset from the body origin (needs the attitude block q)")
        max_range: float | None = Field(None, gt=0.0, description="m: a longer range is malformed (not "
                                        "physical for the sensor; None: no limit)")
        gdop_warn: float | None = Field(10.0, gt=0.0, description="check(): warn when the GDOP of the beacons "
                                        "at the estimated position exceeds this (None: never)")
        mirror_warn_sigma: float | None = Field(3.0, gt=0.0, description="check(): with beacons on one line "
                                                "(2-D) or plane (3-D), warn when the estimate is closer to it than "
                                                "this many standard deviations (None: never)")

    def __init__(self, params=None, context=None, bound: tuple[str, ...] = ()):
        super().__init__(params, context)
        ctx = self.context
        if ctx.layout is None or "p" not in ctx.layout:
            raise ConfigError("range needs a state with a position block 'p'")
        self._p = ctx.layout["p"]
        self._dp = self._p.stop - self._p.start
        names = self.params.beacons if self.params.beacons is not None else list(ctx.beacons)
        if not names:
            raise ConfigError("range needs beacons: define them under 'beacons:' at the top of the config")
        unknown = [b for b in names if b not in ctx.beacons]
        if unknown:
            raise ConfigError(f"range: unknown beacon(s) {unknown}; the config defines {sorted(ctx.beacons)}")
        short = [b for b in names if len(ctx.beacons[b]) < self._dp]
        if short:
            raise ConfigError(f"range: beacon(s) {short} have {len(ctx.beacons[short[0]])} coordinates but the "
                              f"state position is {self._dp}-D")
        self._known = frozenset(names)
        uncal = sorted(set(self.params.calibration) - self._known)
        if uncal:
            raise ConfigError(f"range: calibration of unknown beacon(s) {uncal}; the sensor's beacons are "
                              f"{sorted(self._known)}")
        self._lever = None
        if self.params.lever_arm is not None:
            if "q" not in ctx.layout or ctx.layout.block("q").kind != "quaternion" or self._dp != 3:
                raise ConfigError("range: lever_arm needs a 3-D position p and an attitude quaternion block q in "
                                  f"the state (the state is {ctx.layout!r})")
            self._q = ctx.layout["q"]
            self._lever = np.array(self.params.lever_arm, float)
        self._all = np.array([ctx.beacons[b] for b in names], float)
        self._all_dz2 = ((self.params.tag_z - self._all[:, 2]) ** 2 if (self._all.shape[1] == 3 and self._dp == 2)
                         else np.zeros(len(names)))
        self._all = self._all[:, : self._dp] if self._all.shape[1] >= self._dp else self._all
        self.degenerate = _degenerate_hull(self._all, self._dp)
        self.bound = bound
        self.dim = max(1, len(bound))
        if bound:
            B = np.array([ctx.beacons[b] for b in bound], float)
            if B.shape[1] < self._dp:
                raise ConfigError(f"range: beacons are {B.shape[1]}-D but the state position is {self._dp}-D")
            self._B = B[:, : self._dp]
            self._dz2 = (self.params.tag_z - B[:, 2]) ** 2 if (B.shape[1] == 3 and self._dp == 2) else np.zeros(len(bound))
            cal = self.params.calibration
            self._scale = np.array([cal[b].scale if b in cal else 1.0 for b in bound])
            self._bias = np.array([cal[b].bias if b in cal else 0.0 for b in bound])
            self._calibrated = bool(np.any(self._scale != 1.0) or np.any(self._bias != 0.0))
        self._bind = lru_cache(maxsize=256)(self._make_bound)

    def _make_bound(self, names: tuple[str, ...]) -> "RangeModel":
        return RangeModel(self.params, self.context, names)

    def _tag(self, x: np.ndarray) -> np.ndarray:
        """Position of the tag (..., dp): p, or p + C_b^n(q) l with a lever arm."""
        p = x[..., self._p]
        if self._lever is None:
            return p
        return p + rotate(x[..., self._q], self._lever)

    def h(self, x: np.ndarray) -> np.ndarray:
        d = self._tag(x)[..., None, :] - self._B  # (..., k, dp)
        r = np.sqrt(np.einsum("...kd,...kd->...k", d, d) + self._dz2)
        return self._scale * r + self._bias if self._calibrated else r

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        d = self._tag(x) - self._B
        r = np.sqrt(np.einsum("kd,kd->k", d, d) + self._dz2)
        u = d / np.maximum(r, 1e-12)[:, None]           # unit line of sight (k, dp), d d_i / d tag
        if self._calibrated:
            u = u * self._scale[:, None]
        H = np.zeros((len(self.bound), x.shape[-1]))
        H[:, self._p] = u
        if self._lever is not None:                      # d tag / d q = d(C_b^n(q) l)/dq (3, 4)
            H[:, self._q] = u @ rotate_jacobian(x[self._q], self._lever)
        return H

    def jacobian_batch(self, x: np.ndarray) -> np.ndarray:
        """dh/dx (N, k, n) at states x (N, n) (batched filters, fusion.batch): :meth:`jacobian` row by row
        in one vectorised evaluation."""
        d = self._tag(x)[:, None, :] - self._B                     # (N, k, dp)
        r = np.sqrt(np.einsum("Nkd,Nkd->Nk", d, d) + self._dz2)
        u = d / np.maximum(r, 1e-12)[..., None]
        if self._calibrated:
            u = u * self._scale[:, None]
        H = np.zeros((x.shape[0], len(self.bound), x.shape[-1]))
        H[:, :, self._p] = u
        if self._lever is not None:
            from fusion.batch.models import batch_H_rows
            H[:, :, self._q] = batch_H_rows(lambda xi: self.jacobian(xi)[:, self._q], x)
        return H

    # ------------------------------------------------------------------ geometry check
    def geometry(self, x: np.ndarray, P: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Geometry of the sensor's beacons at the position of states ``x`` (..., n); ``P`` (..., n, n).

        ``gdop`` (...): sqrt(trace((H^T H)^-1)) with H the unit line-of-sight rows of every beacon (inf when
        singular): a single fix from one range to each beacon has position sd ~ GDOP x range sd.
        ``offset_m`` (degenerate layouts only): distance of the estimate from the beacons' line (2-D) or
        plane (3-D), m; ``offset_sigma`` (needs P): that distance over the belief's sd in that direction;
        the mirror image of the estimate across the line is 2 x offset_sigma standard deviations away.
        Values are arrays of the leading shape of ``x`` (0-d for one state).
        """
        p = np.asarray(x, float)[..., self._p]
        if self._all.shape[1] != self._dp:
            return {"gdop": np.full(p.shape[:-1], np.nan)}
        d = p[..., None, :] - self._all                                   # (..., k, dp)
        r = np.sqrt(np.einsum("...kd,...kd->...k", d, d) + self._all_dz2)
        H = d / np.maximum(r, 1e-12)[..., None]
        w = np.linalg.eigvalsh(np.einsum("...kd,...ke->...de", H, H))    # ascending
        ok = w[..., 0] > 1e-12 * np.maximum(w[..., -1], 1e-300)
        gdop = np.where(ok, np.sqrt(np.sum(1.0 / np.where(ok[..., None], w, 1.0), axis=-1)), np.inf)
        out = {"gdop": gdop}
        if self.degenerate is not None:
            a, basis = self.degenerate
            rel = p - a
            perp = rel - (rel @ basis) @ basis.T
            off = np.linalg.norm(perp, axis=-1)
            out["offset_m"] = off
            if P is not None:
                n = np.where((off > 1e-9)[..., None], perp / np.maximum(off, 1e-9)[..., None],
                             _any_normal(basis, self._dp))
                Pp = np.asarray(P, float)[..., self._p, self._p]
                var = np.einsum("...i,...ij,...j->...", n, Pp, n)
                out["offset_sigma"] = off / np.sqrt(np.maximum(var, 1e-300))
        return out

    def warnings(self, geometry: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Boolean arrays (gdop_warning, mirror_warning) of a ``geometry`` result, by the thresholds."""
        pw = self.params
        g = np.asarray(geometry["gdop"])
        gw = g > pw.gdop_warn if pw.gdop_warn is not None else np.zeros(g.shape, bool)
        off = geometry.get("offset_sigma")
        mw = (np.asarray(off) < pw.mirror_warn_sigma if (off is not None and pw.mirror_warn_sigma is not None)
              else np.zeros(g.shape, bool))
        return gw, mw

    def check(self, belief: Belief, sensor: str | None = None) -> list[Event]:
        """``warning`` Events for a degenerate geometry at the belief's mean: GDOP above ``gdop_warn``,
        or (beacons on one line/plane) the estimate within ``mirror_warn_sigma`` sd of that line/plane, where
        the filter can cross to the mirror image and stay there (no gate can tell: it fits the ranges)."""
        g = self.geometry(belief.x, belief.cov)
        gw, mw = self.warnings(g)
        ev: list[Event] = []
        pw = self.params
        where = ", ".join(f"{v:.2f}" for v in np.asarray(belief.x)[self._p])
        if gw:
            ev.append(Event(belief.t, "warning", sensor, f"range: GDOP {float(g['gdop']):.3g} at ({where}) exceeds "
                            f"{pw.gdop_warn:g}: the beacons constrain the position poorly here"))
        if mw:
            kind = ("point", "line", "plane")[self.degenerate[1].shape[1]]  # type: ignore[index]
            ev.append(Event(belief.t, "warning", sensor, f"range: estimate ({where}) is "
                            f"{float(g['offset_sigma']):.2g} sd ({float(g['offset_m']):.2f} m) from the {kind} of the "
                            f"beacons {', '.join(sorted(self._known))}: its mirror image fits the ranges as well; "
                            "the filter may cross to it"))
        return ev

    def observe(self, message: Message) -> Observation | None:
        """Observation of ``beacon range [beacon range ...]`` (m). MalformedMessage, with the reason, for
        a wrong field count, a beacon that is no name or not one of this sensor's, a range that is not a
        finite number >= 0 or is beyond ``max_range``."""
        vals = message.values
        if len(vals) < 2 or len(vals) % 2:
            raise MalformedMessage(f"range expects 'beacon range' pairs, got {len(vals)} value(s) {vals!r}")
        names = tuple(vals[0::2])
        for b in names:
            if not isinstance(b, str):
                raise MalformedMessage(f"range expects a beacon name, got {b!r} (fields 'beacon range', "
                                       f"beacons {', '.join(sorted(self._known))})")
            if b not in self._known:
                raise MalformedMessage(f"unknown beacon {b!r} (known: {', '.join(sorted(self._known))})")
        if len(names) > 1 and len(set(names)) != len(names):   # (also bounds a message to one range a beacon)
            raise MalformedMessage(f"beacon {next(b for b in names if names.count(b) > 1)!r} twice in one message")
        try:
            z = np.array(vals[1::2], float)
        except (TypeError, ValueError):
            raise MalformedMessage(f"range expects numbers, got {vals[1::2]!r}") from None
        if z.shape != (len(names),):   # a sequence where a number belongs (a message from another source)
            raise MalformedMessage(f"range expects numbers, got {vals[1::2]!r}")
        if not np.all(np.isfinite(z)):
            raise MalformedMessage(f"non-finite range in {vals!r}")
        if np.any(z < 0):
            raise MalformedMessage(f"negative range {z.min()} m")
        mx = self.params.max_range
        if mx is not None and np.any(z > mx):
            raise MalformedMessage(f"range {z.max()} m beyond max_range {mx} m")
        if np.any(z > MAX_MAGNITUDE):
            raise MalformedMessage(f"range {z.max()} m beyond {MAX_MAGNITUDE:g} (its square overflows float64)")
        return Observation(message.t, z, self._bind(names))


def _degenerate_hull(B: np.ndarray, dp: int, tol: float = 1e-6) -> tuple[np.ndarray, np.ndarray] | None:
    """(point, orthonormal basis (dp, k)) of the affine hull of the beacons B (m, dp) when its dimension k
    is below dp (all on one line in 2-D, one plane in 3-D), else None. ``tol`` is relative to the spread."""
    if B.shape[1] != dp or B.shape[0] == 0:
        return None
    a = B.mean(axis=0)
    C = B - a
    if B.shape[0] == 1:
        return a, np.zeros((dp, 0))
    _, s, Vt = np.linalg.svd(C, full_matrices=True)
    scale = max(float(s[0]), 1e-12)
    k = int(np.sum(s > tol * scale))
    if k >= dp:
        return None
    return a, Vt[:k].T


def _any_normal(basis: np.ndarray, dp: int) -> np.ndarray:
    """A unit vector orthogonal to the columns of ``basis`` (dp, k), k < dp."""
    Q, _ = np.linalg.qr(np.concatenate([basis, np.eye(dp)], axis=1))
    return Q[:, basis.shape[1]]
