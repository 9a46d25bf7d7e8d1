"""The health watch of a batch of lock-step trials (fusion.sweep.batched): fusion.health.watch.HealthWatch's
records, kept for N trials at once from the batched filters' per-trial NIS and accepted arrays, so a batched
sweep judges each trial by the same rule as ``fusion run``."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from fusion.health.spec import HealthSpec
from fusion.health.watch import lockout_limits

__all__ = ["BatchHealthWatch"]


class _Sensor:
    """One sensor's records over N trials (the arrays of fusion.health.watch.SensorWatch, one a trial)."""

    def __init__(self, n: int, limit_s: float | None):
        self.limit_s = limit_s
        self.updates = 0
        self.accepted = np.zeros(n, np.int64)
        self.first_t = self.last_t = math.nan
        self.run_start = np.full(n, math.nan)
        self.run_count = np.zeros(n, np.int64)
        self.run_last = np.full(n, math.nan)
        self.longest = [(math.nan, 0.0, 0)] * n
        self.lockouts: list[list[tuple[float, float, int]]] = [[] for _ in range(n)]
        self.windows: list[list[tuple[float, float, float, int]]] = [[] for _ in range(n)]
        self.w_start = np.full(n, math.nan)
        self.w_last = np.full(n, math.nan)
        self.w_sum = np.zeros(n)
        self.w_dof = np.zeros(n, np.int64)

    def add(self, t: float, accepted: np.ndarray, nis: np.ndarray, dof: int, window_dof: int) -> None:
        self.updates += 1
        if self.updates == 1:
            self.first_t = t
        self.last_t = t
        self.accepted += accepted
        ended = accepted & (self.run_count > 0)
        for i in np.flatnonzero(ended):
            self._end_run(int(i))
        good = accepted & np.isfinite(nis)
        fresh = good & (self.w_dof == 0)
        self.w_start[fresh] = t
        self.w_last[good] = t
        self.w_sum[good] += nis[good]
        self.w_dof[good] += dof
        for i in np.flatnonzero(self.w_dof >= window_dof):
            self.windows[i].append((float(self.w_start[i]), float(self.w_last[i]), float(self.w_sum[i]),
                                    int(self.w_dof[i])))
            self.w_sum[i], self.w_dof[i] = 0.0, 0
        rejected = ~accepted
        starting = rejected & (self.run_count == 0)
        self.run_start[starting] = t
        self.run_count[rejected] += 1
        self.run_last[rejected] = t

    def _end_run(self, i: int) -> None:
        span = float(self.run_last[i] - self.run_start[i])
        run = (float(self.run_start[i]), span, int(self.run_count[i]))
        best = self.longest[i]
        if span > best[1] or (span == best[1] and run[2] > best[2]):
            self.longest[i] = run
        if self.limit_s is not None and span > self.limit_s:
            self.lockouts[i].append(run)
        self.run_start[i], self.run_count[i], self.run_last[i] = math.nan, 0, math.nan

    def report(self, i: int) -> dict[str, Any]:
        tail = None
        if self.run_count[i]:
            tail = (float(self.run_start[i]), float(self.run_last[i] - self.run_start[i]), int(self.run_count[i]))
        runs, longest = list(self.lockouts[i]), self.longest[i]
        if tail is not None:
            if tail[1] > longest[1]:
                longest = tail
            if self.limit_s is not None and tail[1] > self.limit_s:
                runs.append(tail)
        return {"updates": self.updates, "accepted": int(self.accepted[i]), "first_t": self.first_t,
                "last_t": self.last_t, "limit_s": self.limit_s, "lockouts": runs, "longest_rejected": longest,
                "tail_rejected": tail, "windows": list(self.windows[i])}


class BatchHealthWatch:
    """HealthWatch for ``n`` lock-step trials of ``system`` (one variant): ``add(sensor, t, accepted (n,),
    nis (n,), dof)`` per update, ``report(i)`` the watch report of trial ``i``."""

    def __init__(self, system: Any, n: int, spec: HealthSpec | None = None):
        self.spec = spec if spec is not None else HealthSpec()
        self.sensors = {name: _Sensor(n, limit) for name, limit in lockout_limits(system, self.spec).items()}

    def add(self, sensor: str, t: float, accepted: np.ndarray, nis: np.ndarray, dof: int) -> None:
        w = self.sensors.get(sensor)
        if w is not None:
            w.add(float(t), np.asarray(accepted, bool), np.asarray(nis, float), int(dof), self.spec.nis_window_dof)

    def report(self, i: int) -> dict[str, dict[str, Any]]:
        return {name: w.report(i) for name, w in self.sensors.items() if w.updates}
