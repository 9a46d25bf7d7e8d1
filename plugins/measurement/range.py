"""Measurement ``range``: distances to named beacons, paper 001 eq. 6.

A message is ``beacon range`` (one range), or several pairs ``B1 r1 B2 r2 ...``; the model binds to the
beacons a message names. With a 2-D state and 3-D beacons the tag is at the fixed height ``tag_z``:

.. math::
    r_i = \\sqrt{(p_x - b_{i,x})^2 + (p_y - b_{i,y})^2 [+ (p_z - b_{i,z})^2 \\text{ or } (z_{tag} - b_{i,z})^2]}
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from fusion.api import ConfigError, MalformedMessage, MeasurementModel, Message, Observation, Params


class RangeModel(MeasurementModel):
    """Ranges (m) from the position block ``p`` (2-D or 3-D) to named beacons (config ``beacons:``).

    Params: ``beacons``: the beacons this sensor may range to (default: all); ``tag_z``: the tag's height
    (m, same frame as the beacons) used when the state is 2-D and the beacons are 3-D."""

    name = "range"
    dim = 1

    class Params(Params):
        beacons: list[str] | None = None
        tag_z: float = 0.0

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
        self._known = frozenset(names)
        self.bound = bound
        self.dim = max(1, len(bound))
        if bound:
            B = np.array([ctx.beacons[b] for b in bound], float)
            if B.shape[1] < self._dp:
                raise ConfigError(f"range: beacons are {B.shape[1]}-D but the state position is {self._dp}-D")
            self._B = B[:, : self._dp]
            self._dz2 = (self.params.tag_z - B[:, 2]) ** 2 if (B.shape[1] == 3 and self._dp == 2) else np.zeros(len(bound))
        self._bind = lru_cache(maxsize=256)(self._make_bound)

    def _make_bound(self, names: tuple[str, ...]) -> "RangeModel":
        return RangeModel(self.params, self.context, names)

    def h(self, x: np.ndarray) -> np.ndarray:
        d = x[..., None, self._p] - self._B  # (..., k, dp)
        return np.sqrt(np.einsum("...kd,...kd->...k", d, d) + self._dz2)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        d = x[self._p] - self._B
        r = np.sqrt(np.einsum("kd,kd->k", d, d) + self._dz2)
        H = np.zeros((len(self.bound), x.shape[-1]))
        H[:, self._p] = d / np.maximum(r, 1e-12)[:, None]
        return H

    def observe(self, message: Message) -> Observation | None:
        vals = message.values
        if len(vals) < 2 or len(vals) % 2:
            raise MalformedMessage(f"range expects 'beacon range' pairs, got {len(vals)} values")
        names = tuple(vals[0::2])
        for b in names:
            if not isinstance(b, str):
                raise MalformedMessage(f"range expects a beacon name, got {b!r}")
            if b not in self._known:
                raise MalformedMessage(f"unknown beacon {b!r} (known: {', '.join(sorted(self._known))})")
        try:
            z = np.array(vals[1::2], float)
        except ValueError:
            raise MalformedMessage(f"range expects numbers, got {vals[1::2]!r}") from None
        if np.any(z < 0):
            raise MalformedMessage(f"negative range {z.min()}")
        return Observation(message.t, z, self._bind(names))
