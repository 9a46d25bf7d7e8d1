"""The health watch of a run: a sink (``on_estimate``) that ``fusion run`` and ``fusion sweep`` add beside
their outputs. It reads what every update estimate already carries (``Estimate.sensor`` and its
``UpdateResult``: accepted or not, the NIS and its dof) and keeps, per measurement sensor, in memory that
grows only with the number of NIS windows:

- runs of updates rejected in a row (a lock-out): each one longer than the sensor's limit, and the last;
- the NIS of the accepted updates summed over windows of ``nis_window_dof`` degrees of freedom, each kept
  as ``(t first, t last, NIS sum, dof sum)`` for the chi-square test of fusion.health.rule.

Estimates without an update (fixed-rate outputs, replays) are ignored; with ``output.on_update: false``
the watch sees no update and the rule judges from the summary alone."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from fusion.health.spec import HealthSpec

__all__ = ["HealthWatch", "SensorWatch", "DEFAULT_LOCKOUT_S"]

#: Rejections in a row of a sensor without a recovery that last to its last update are a lock-out from this
#: long (the default RecoverySpec's after_s).
DEFAULT_LOCKOUT_S = 2.0


@dataclass
class SensorWatch:
    """What the watch keeps of one sensor (times in s, sensor time)."""

    limit_s: float | None                 # a rejected run longer than this is a lock-out (None: only at the end)
    updates: int = 0
    accepted: int = 0
    first_t: float = math.nan
    last_t: float = math.nan
    run_start: float = math.nan           # the current run of rejected updates
    run_count: int = 0
    run_last: float = math.nan
    longest: tuple[float, float, int] = (math.nan, 0.0, 0)   # (start, span s, count) of the longest run
    lockouts: list[tuple[float, float, int]] = field(default_factory=list)  # (start, span, count) over limit_s
    windows: list[tuple[float, float, float, int]] = field(default_factory=list)
    _w: list[float] = field(default_factory=lambda: [math.nan, math.nan, 0.0, 0])

    def add(self, t: float, accepted: bool, nis: float, dof: int, window_dof: int) -> None:
        self.updates += 1
        if self.updates == 1:
            self.first_t = t
        self.last_t = t
        if accepted:
            self.accepted += 1
            self._end_run()
            if dof >= 1 and math.isfinite(nis):
                w = self._w
                if w[3] == 0:
                    w[0] = t
                w[1], w[2], w[3] = t, w[2] + nis, w[3] + dof
                if w[3] >= window_dof:
                    self.windows.append((w[0], w[1], w[2], int(w[3])))
                    self._w = [math.nan, math.nan, 0.0, 0]
            return
        if self.run_count == 0:
            self.run_start = t
        self.run_count += 1
        self.run_last = t

    def _end_run(self) -> None:
        if not self.run_count:
            return
        span = self.run_last - self.run_start
        run = (self.run_start, span, self.run_count)
        if span > self.longest[1] or (span == self.longest[1] and self.run_count > self.longest[2]):
            self.longest = run
        if self.limit_s is not None and span > self.limit_s:
            self.lockouts.append(run)
        self.run_start, self.run_count, self.run_last = math.nan, 0, math.nan

    def tail(self) -> tuple[float, float, int] | None:
        """The run of rejections still going at the sensor's last update, or None."""
        if not self.run_count:
            return None
        return (self.run_start, self.run_last - self.run_start, self.run_count)

    def report(self) -> dict[str, Any]:
        tail = self.tail()
        runs = list(self.lockouts)
        longest = self.longest
        if tail is not None:
            if tail[1] > longest[1]:
                longest = tail
            if self.limit_s is not None and tail[1] > self.limit_s:
                runs.append(tail)
        return {"updates": self.updates, "accepted": self.accepted, "first_t": self.first_t, "last_t": self.last_t,
                "limit_s": self.limit_s, "lockouts": runs, "longest_rejected": longest, "tail_rejected": tail,
                "windows": list(self.windows)}


def lockout_limits(system: Any, spec: HealthSpec) -> dict[str, float | None]:
    """Each measurement sensor's lock-out limit (s): the config's ``health.lockout_s``, else the sensor's
    recovery time, else None (judged against the run's end)."""
    limits: dict[str, float | None] = {}
    for name, s in system.sensors.items():
        if s.role == "measurement":
            limit = spec.lockout_s
            if limit is None and s.recovery is not None:
                limit = float(s.recovery.after_s)
            limits[name] = limit
    return limits


class HealthWatch:
    """Sink of a run's estimates that records what fusion.health.rule needs (see the module).

    :param system: the wired system (its sensors' roles and recoveries).
    :param spec: the config's ``health`` limits (its ``lockout_s`` and ``nis_window_dof``)."""

    def __init__(self, system: Any, spec: HealthSpec | None = None):
        self.spec = spec if spec is not None else HealthSpec()
        self.sensors = {name: SensorWatch(limit) for name, limit in lockout_limits(system, self.spec).items()}

    def on_estimate(self, estimate: Any) -> None:
        up = estimate.update
        if up is None or estimate.reason != "update":
            return
        w = self.sensors.get(estimate.sensor)
        if w is None:
            return
        w.add(float(estimate.t), bool(up.accepted), float(up.nis), int(up.innovation.size), self.spec.nis_window_dof)

    def close(self) -> None:
        """Nothing to flush (a sink's close)."""

    def report(self) -> dict[str, dict[str, Any]]:
        """Per sensor with at least one update: see :meth:`SensorWatch.report`."""
        return {name: w.report() for name, w in self.sensors.items() if w.updates}
