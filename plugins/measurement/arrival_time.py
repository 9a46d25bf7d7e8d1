"""Measurement ``arrival_time``: the arrival time of one beacon's pulse (paper 003 eq. 11, corrected form).

.. math::
    t_i = t + \\frac{\\sqrt{(x - x_i)^2 + (y - y_i)^2 + (z - z_i)^2}}{c}

with t the firing time of the latest firing (state block ``t`` of ``firing_clock``), (x, y, z) the
position block ``p`` and (x_i, y_i, z_i) beacon i (config ``beacons:``). Jacobian:
``dt_i/dp = (p - b_i)^T / (c d_i)``, ``dt_i/dt = 1``.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from pydantic import Field

from fusion.api import ConfigError, Fix, MeasurementModel, Message, Observation, Params

from fusion_plugins.solvers.initial_fix import observe_initial
from fusion_plugins.solvers.tdoa_geometric import parse_arrival


class ArrivalTime(MeasurementModel):
    """Arrival time (s, receiver clock) of a pulse from a named beacon (paper 003 eq. 11).

    Messages: ``beacon arrival [receiver]`` (the ``arrival_time`` simulator's fields); z = arrival (s).
    The state needs blocks ``p`` (3) and ``t`` (firing time, s). The initial state fix of ``tdoa_geometric``
    (``output: initialise``: a fusion.api.Fix of the position and firing time with their covariance,
    :mod:`fusion_plugins.solvers.initial_fix`) is observed as such, the filter's first update. Params: ``speed_of_sound`` c (m/s), ``beacons`` (default all)."""

    name = "arrival_time"
    dim = 1

    class Params(Params):
        speed_of_sound: float = Field(340.0, gt=0.0, description="c (m/s); paper 003: 340 from the temperature")
        beacons: list[str] | None = Field(None, description="beacons this receiver hears (default: all)")

    def __init__(self, params=None, context=None, bound: str | None = None):
        super().__init__(params, context)
        ctx = self.context
        lay = ctx.layout
        if lay is None or "p" not in lay or "t" not in lay or lay["p"].stop - lay["p"].start != 3:
            raise ConfigError("arrival_time needs a state with a 3-D position block 'p' and a firing time 't' "
                              "(process firing_clock)")
        self._p, self._t = lay["p"], lay["t"].start
        names = self.params.beacons if self.params.beacons is not None else list(ctx.beacons)
        unknown = [b for b in names if b not in ctx.beacons]
        if unknown or not names:
            raise ConfigError(f"arrival_time: unknown or no beacon(s) {unknown}; the config defines "
                              f"{sorted(ctx.beacons)}")
        if any(len(ctx.beacons[b]) != 3 for b in names):
            raise ConfigError("arrival_time: beacons need 3 coordinates (m)")
        self._known = tuple(names)
        self.bound = bound
        self._inv_c = 1.0 / self.params.speed_of_sound
        if bound is not None:
            self._b = np.asarray(ctx.beacons[bound], float)
        self._bind = lru_cache(maxsize=64)(lambda name: ArrivalTime(self.params, self.context, name))

    def h(self, x: np.ndarray) -> np.ndarray:
        d = x[..., self._p] - self._b
        return (x[..., self._t] + np.sqrt(np.einsum("...d,...d->...", d, d)) * self._inv_c)[..., None]

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        d = x[self._p] - self._b
        H = np.zeros((1, x.shape[-1]))
        H[0, self._p] = d * (self._inv_c / max(float(np.sqrt(d @ d)), 1e-12))
        H[0, self._t] = 1.0
        return H

    def observe(self, message: Message | Fix) -> Observation | None:
        if isinstance(message, Fix):              # the initial state fix of tdoa_geometric (initialise)
            return observe_initial(message, self.context)
        label, arrival = parse_arrival(message, self._known)
        return Observation(message.t, np.array([arrival]), self._bind(label))
