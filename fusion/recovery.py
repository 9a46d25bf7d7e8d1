"""Recovery from divergence and lock-out, per sensor, off unless configured.

A filter that has accepted one bad measurement (or drifted during an outage) can become so sure of a
wrong state that its gate rejects every later, correct measurement: it is locked out and never
recovers. PX4's EKF2 resets its position and velocity to the GNSS after a time without aiding
(``EKF2_NOAID_TOUT``); ArduPilot's EKF3 has a glitch radius beyond which GPS is no longer rejected but
forces a reset. Here, per sensor (``sensors.NAME.recovery`` in the config)::

    recovery: {after_s: 2.0, min_rejected: 3, action: reset, blocks: [p]}

The lock-out signature is a sustained run of rejections of a sensor whose measurements agree with *each
other* while they disagree with the belief, whatever the NIS: a filter whose error grows with its
covariance (an INS drifting without its fixes) keeps every NIS just above the gate, and a rule on the NIS
magnitude never fires (e.g. good fixes refused in a row at NIS 17.5-30.2 against a gate of 16.3 while the
error grows past 12 m). So when every update of the sensor has been rejected for at least ``after_s`` seconds
(and at least ``min_rejected`` of them), and the rejected measurements agree with each other, the
measurement that completes the streak is used to recover, then fused.

*Agreement* (``agreement_probability``, default 0.999; null turns the test off): the innovations of the
streak, per measurement model (a range bound to one beacon is compared with the ranges to that beacon
only), are fitted by a common offset and drift in time (the belief's error and its rate: a wrong position
and velocity), weighted by their innovation covariances; the streak agrees when the chi-square of the
residuals is within that probability (``(n - 2) m`` dof for ``n`` measurements of dimension ``m``; a model
with fewer than 3 measurements in the streak is not tested). A rejected measurement that breaks the
agreement starts the streak again from itself: an echo burst, fixes scattered around a good belief, does
not reset it. Measurements that are consistently wrong the same way (one echo path repeated while the
vehicle stands still) cannot be told from a wrong belief by this sensor alone.
``nis_factor`` (default 1: every rejection counts) additionally restricts the streak to rejections with a
NIS at least that many times the gate's threshold; a smaller NIS ends the streak.

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
from fusion.chisquare import chi2

__all__ = ["RecoverySpec", "LockoutWatch", "recover"]


class RecoverySpec(BaseModel):
    """``sensors.NAME.recovery`` (see fusion.recovery)."""

    model_config = ConfigDict(extra="forbid")

    after_s: float = Field(2.0, gt=0.0, allow_inf_nan=False, description="s of rejections before recovering")
    min_rejected: int = Field(3, ge=1, description="rejected updates in that time at least")
    nis_factor: float = Field(1.0, ge=1.0, allow_inf_nan=False,
                              description="count only rejections with a NIS at least this many times the gate's "
                              "threshold (1: every rejection)")
    agreement_probability: float | None = Field(
        0.999, gt=0.0, lt=1.0, allow_inf_nan=False,
        description="the streak's measurements must agree with each other (an offset and drift in time fit "
                    "their innovations) at this chi-square probability; null: not tested")
    action: Literal["reset", "inflate"] = "reset"
    blocks: list[str] = Field(default_factory=lambda: ["p"], description="state blocks to reset or inflate")
    inflate: float = Field(10.0, gt=1.0, allow_inf_nan=False, description="action inflate: sd factor")
    also_inflate: list[str] = Field(default_factory=list, description="action reset: blocks whose sd grow by "
                                    "``inflate`` as well (what drifted with the reset ones, e.g. v)")


class LockoutWatch:
    """The rejection streak of one sensor (see the module): its start, count and, for the agreement test,
    the streak's innovations by measurement model."""

    def __init__(self, spec: RecoverySpec):
        self.spec = spec
        self.start = math.nan
        self.count = 0
        self._seen: dict[object, list[tuple[float, np.ndarray, np.ndarray]]] = {}

    def update(self, t: float, accepted: bool, nis: float, threshold: float | None,
               innovation: np.ndarray | None = None, S: np.ndarray | None = None, key: object = None) -> bool:
        """Record one update at ``t`` (s) with its NIS and its gate's ``threshold`` (None: no gate), and for
        the agreement test its ``innovation`` (m,), covariance ``S`` (m, m) and measurement model ``key``
        (None: the sensor's only one). True when the sensor is locked out (this measurement recovers)."""
        far = threshold is None or not (nis < self.spec.nis_factor * threshold)  # NaN NIS counts as far
        if accepted or not far:
            self.clear()
            return False
        entry = None if self.spec.agreement_probability is None else _entry(t, innovation, S)
        if entry is not None:
            group = self._seen.setdefault((key, entry[1].size), [])
            group.append(entry)
            if self.count and not _agree(group, self.spec.agreement_probability):  # type: ignore[arg-type]
                self.clear()   # it disagrees with the streak: the streak starts again from it
                self._seen[(key, entry[1].size)] = [entry]
        if self.count == 0:
            self.start = t
        self.count += 1
        return self.count >= self.spec.min_rejected and t - self.start >= self.spec.after_s

    def clear(self) -> None:
        self.start, self.count = math.nan, 0
        self._seen = {}


def _entry(t: float, y: np.ndarray | None, S: np.ndarray | None) -> tuple[float, np.ndarray, np.ndarray] | None:
    """(t, y, S^-1) of a rejected update, or None when it cannot be tested (no or non-finite innovation,
    S not positive definite)."""
    if y is None or S is None:
        return None
    y = np.asarray(y, dtype=float).ravel()
    S = np.asarray(S, dtype=float)
    if y.size == 0 or S.shape != (y.size, y.size) or not (np.isfinite(y).all() and np.isfinite(S).all()):
        return None
    try:
        L = np.linalg.cholesky(0.5 * (S + S.T))
    except np.linalg.LinAlgError:
        return None
    Li = np.linalg.inv(L)
    return float(t), y, Li.T @ Li


def _agree(group: list[tuple[float, np.ndarray, np.ndarray]], prob: float) -> bool:
    """Whether the innovations ``y_k`` (m,) of one model fit ``a + b (t_k - mean t)`` within the chi-square
    ``prob`` of their residuals, weighted by ``W_k = S_k^-1`` (generalised least squares; True below 3)."""
    n = len(group)
    if n < 3:
        return True
    m = group[0][1].size
    tau = np.array([g[0] for g in group])
    tau -= tau.mean()
    Y = np.stack([g[1] for g in group])            # (n, m)
    W = np.stack([g[2] for g in group])            # (n, m, m)
    Wy = np.einsum("kij,kj->ki", W, Y)
    N = np.block([[W.sum(0), np.einsum("k,kij->ij", tau, W)],
                  [np.einsum("k,kij->ij", tau, W), np.einsum("k,kij->ij", tau * tau, W)]])
    rhs = np.concatenate([Wy.sum(0), tau @ Wy])
    theta = np.linalg.lstsq(N, rhs, rcond=None)[0]
    r = Y - theta[:m] - tau[:, None] * theta[m:]
    chi = float(np.einsum("ki,kij,kj->", r, W, r))
    return chi <= chi2.ppf(prob, (n - 2) * m)


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
