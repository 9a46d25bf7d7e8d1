"""Per-sensor innovation histories for the time-series panels, bounded ring buffers (worker thread).

Each update (accepted or rejected) of a measurement sensor adds one ``Sample``: its sensor time, the
test ratio ``NIS / gate threshold`` (PX4's innovation test ratio: under ~0.5 normal, over 1 rejected;
nan when the sensor has no gate with a threshold), the NIS itself, whether the gate accepted it, and
the innovation ``y = z - h(x)`` with ``sqrt(diag S)`` (units of the measurement: m for a range).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from fusion.api import Estimate, HasThreshold, has


@dataclass(frozen=True)
class Sample:
    t: float
    ratio: float
    nis: float
    accepted: bool
    y: tuple[float, ...]
    sd: tuple[float, ...]


class InnovationHistory:
    """The last ``maxlen`` samples per sensor; ``gates`` maps a sensor to its gate (the ratio needs its
    ``threshold(dim)``: fusion.api.HasThreshold)."""

    def __init__(self, gates: Mapping[str, Any], maxlen: int = 600):
        self.gates = dict(gates)
        self.thresholds = {n: g.threshold for n, g in self.gates.items() if has(g, HasThreshold)}
        self.maxlen = maxlen
        self.samples: dict[str, deque[Sample]] = {}

    def on_estimate(self, est: Estimate) -> None:
        up = est.update
        if up is None or est.sensor is None:
            return
        y = np.asarray(up.innovation, dtype=float).reshape(-1)
        S = np.asarray(up.S, dtype=float).reshape(y.size, y.size) if y.size else np.zeros((0, 0))
        nis = float(up.nis)
        threshold = self.thresholds.get(est.sensor)
        ratio = math.nan
        if threshold is not None and y.size:
            try:
                ratio = nis / float(threshold(y.size))
            except (ValueError, ZeroDivisionError):
                ratio = math.nan
        sd = np.sqrt(np.clip(np.diag(S), 0.0, None)) if y.size else y
        buf = self.samples.get(est.sensor)
        if buf is None:
            buf = self.samples[est.sensor] = deque(maxlen=self.maxlen)
        buf.append(Sample(est.t, ratio, nis, bool(up.accepted), tuple(y.tolist()), tuple(sd.tolist())))

    def snapshot(self) -> dict[str, tuple[Sample, ...]]:
        return {k: tuple(v) for k, v in self.samples.items()}
