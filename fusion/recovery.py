"""Recovery from divergence and lock-out (issue 10 item 7), per sensor, off unless configured.

A filter that has accepted one bad measurement (or drifted during an outage) can become so sure of a
wrong state that its gate rejects every later, correct measurement: it is locked out and never
recovers. PX4's EKF2 resets its position and velocity to the GNSS after a time without aiding
(``EKF2_NOAID_TOUT``); ArduPilot's EKF3 has a glitch radius beyond which GPS is no longer rejected but
forces a reset. Here, per sensor (``sensors.NAME.recovery`` in the config)::

    recovery: {after_s: 2.0, min_rejected: 3, nis_factor: 2.0, action: reset, blocks: [p]}

When every update of the sensor has been rejected for at least ``after_s`` seconds (and at least
``min_rejected`` of them), with each NIS at least ``nis_factor`` times its gate's threshold (the
measurements disagree with the belief by far, not marginally), the measurement that completes the
streak is used to recover, then fused:

- ``action: reset``: the listed blocks are re-initialised from the measurement, for a sensor that
  measures them directly (a position fix: the block ``p`` from ``z``, through the model's lever arm when
  it has ``position_from``; a 2-D fix resets the first two elements), with the measurement's covariance
  and no correlation to the rest;
  ``also_inflate`` lists blocks that drifted with them (a velocity) whose sd grow by ``inflate``;
- ``action: inflate``: the covariance of the listed blocks is scaled so their standard deviations grow by
  ``inflate`` (their correlations kept), and the measurement is fused as usual.

Each recovery is a ``reset`` event and counted in the summary's ``health``.
"""
from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from fusion.api import Belief, Event

__all__ = ["RecoverySpec", "LockoutWatch", "recover"]


class RecoverySpec(BaseModel):
    """``sensors.NAME.recovery`` (see fusion.recovery)."""

    model_config = ConfigDict(extra="forbid")

    after_s: float = Field(2.0, gt=0.0, allow_inf_nan=False, description="s of rejections before recovering")
    min_rejected: int = Field(3, ge=1, description="rejected updates in that time at least")
    nis_factor: float = Field(2.0, ge=1.0, allow_inf_nan=False,
                              description="each rejected NIS at least this many times the gate's threshold")
    action: Literal["reset", "inflate"] = "reset"
    blocks: list[str] = Field(default_factory=lambda: ["p"], description="state blocks to reset or inflate")
    inflate: float = Field(10.0, gt=1.0, allow_inf_nan=False, description="action inflate: sd factor")
    also_inflate: list[str] = Field(default_factory=list, description="action reset: blocks whose sd grow by "
                                    "``inflate`` as well (what drifted with the reset ones, e.g. v)")


class LockoutWatch:
    """The rejection streak of one sensor."""

    def __init__(self, spec: RecoverySpec):
        self.spec = spec
        self.start = math.nan
        self.count = 0

    def update(self, t: float, accepted: bool, nis: float, threshold: float | None) -> bool:
        """Record one update; True when the sensor is locked out (the next measurement recovers)."""
        far = threshold is None or not (nis < self.spec.nis_factor * threshold)  # NaN NIS counts as far
        if accepted or not far:
            self.start, self.count = math.nan, 0
            return False
        if self.count == 0:
            self.start = t
        self.count += 1
        return self.count >= self.spec.min_rejected and t - self.start >= self.spec.after_s

    def clear(self) -> None:
        self.start, self.count = math.nan, 0


def recover(spec: RecoverySpec, belief: Belief, layout, obs, R: np.ndarray, filt, sensor: str) -> tuple[Belief, Event]:
    """The belief after recovery with observation ``obs`` (see the module), and its ``reset`` event."""
    x = np.array(belief.x, dtype=float)
    P = np.array(belief.cov, dtype=float)
    idx = np.concatenate([np.arange(layout[b].start, layout[b].stop) for b in spec.blocks])
    def inflate(P: np.ndarray, blocks: list[str]) -> np.ndarray:
        d = np.ones(x.size)
        for b in blocks:
            d[layout[b]] = spec.inflate
        return d[:, None] * P * d[None, :]

    if spec.action == "inflate":
        P = inflate(P, spec.blocks)
        detail = f"{sensor} locked out; sd of {', '.join(spec.blocks)} inflated {spec.inflate:g}x"
    else:
        if spec.also_inflate:
            P = inflate(P, spec.also_inflate)
        to_state = getattr(obs.model, "position_from", None)
        z = np.asarray(obs.z, dtype=float)
        value = to_state(z, x) if to_state is not None else z
        idx = idx[: value.size]  # a horizontal fix resets the horizontal elements only
        x[idx] = value[: idx.size]
        Rb = np.asarray(obs.R if obs.R is not None else R, dtype=float)[: idx.size, : idx.size]
        P[idx, :] = 0.0
        P[:, idx] = 0.0
        P[np.ix_(idx, idx)] = Rb
        detail = f"{sensor} locked out; {', '.join(spec.blocks)} re-initialised from its measurement" + (
            f", sd of {', '.join(spec.also_inflate)} inflated {spec.inflate:g}x" if spec.also_inflate else "")
    return filt.initial_belief(belief.t, x, 0.5 * (P + P.T)), Event(belief.t, "reset", sensor, detail)
