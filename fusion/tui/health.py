"""Health of a live run: per-sensor rate against its expected rate, time since its last accepted
measurement against its limit, problem counts, filter events, and one overall state with its reason.

``HealthMonitor`` is fed in the feed's worker thread (every message, estimate and event) and ``assess()``
builds an immutable ``Health`` for each snapshot. Times are sensor time (s) except ``no data`` on a live
port, which is wall time since the last byte.

- rate (Hz): messages received in the last ``window_s`` seconds of sensor time (so a paused replay
  shows the same numbers whatever the wall clock did);
- expected rate (Hz): given (``fusion tui --expect-rate SENSOR=HZ``) or learned: the mean message rate
  over the sensor's first ``learn_s`` seconds of sensor time (before that, no rate check);
- limit (s) on the time since the last accepted measurement (measurement sensors: an update the gate
  accepted; input sensors: a sample received): given (``--limit SENSOR=S``) or
  ``max(1 s, 10 / expected rate)``;
- overall: ``LOST`` when the source is lost or reconnecting, a live port has sent nothing for
  ``silent_s``, the estimate is not finite, or no sensor is within its limit; ``DEGRADED`` when a sensor
  runs under half its expected rate or is beyond its limit, or the filter repaired its covariance or
  was reset in the last ``recent_s`` seconds; ``OK`` otherwise. The reason names the first cause found,
  in that order.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from fusion.api import Estimate, Event, Message

PROBLEMS = ("rejected", "malformed", "late", "gap", "clock")


@dataclass(frozen=True)
class SensorHealth:
    """One sensor: ``rate``/``expected`` in Hz (nan when unknown), ``since_ok``/``limit`` in s,
    ``counts`` of PROBLEMS, ``status`` ok, slow (under half the expected rate), stale (beyond its limit)
    or waiting (nothing accepted yet)."""

    name: str
    role: str
    rate: float
    expected: float
    since_ok: float
    limit: float
    counts: Mapping[str, int]
    status: str


@dataclass(frozen=True)
class Health:
    """Overall ``state`` (OK, DEGRADED, LOST) with its ``reason``; per-sensor rows; filter events:
    ``repairs`` (covariance not positive definite, repaired), ``resets`` (recovery), ``clock`` events."""

    state: str
    reason: str
    sensors: tuple[SensorHealth, ...]
    repairs: int
    resets: int
    clock: int


class HealthMonitor:
    """Accumulates what ``assess`` needs, in constant memory per sensor."""

    def __init__(self, roles: Mapping[str, str], expected: Mapping[str, float] | None = None,
                 limits: Mapping[str, float] | None = None, learn_s: float = 5.0, silent_s: float = 5.0,
                 recent_s: float = 10.0, window_s: float = 2.0):
        self.roles = dict(roles)
        self.given_rate = dict(expected or {})
        self.given_limit = dict(limits or {})
        self.learn_s, self.silent_s, self.recent_s = learn_s, silent_s, recent_s
        self.window_s = window_s
        self._times: dict[str, deque[float]] = {}
        self.learned: dict[str, float] = {}
        self._first: dict[str, tuple[float, int]] = {}  # sensor -> (first t, messages since)
        self.last_ok: dict[str, float] = {}
        self.counts: dict[str, dict[str, int]] = {}
        self._last_repair_t = self._last_reset_t = -math.inf

    # ------------------------------------------------------------------ feeding (worker thread)
    def on_message(self, msg: Message) -> None:
        name, t = msg.sensor, msg.t
        role = self.roles.get(name)
        if role is None or t - t != 0.0:
            return
        times = self._times.get(name)
        if times is None:
            times = self._times[name] = deque()
        times.append(t)
        while times and times[0] <= t - self.window_s:
            times.popleft()
        if name not in self.learned:
            first = self._first.get(name)
            if first is None:
                self._first[name] = (t, 0)
            else:
                n = first[1] + 1
                self._first[name] = (first[0], n)
                if t - first[0] >= self.learn_s:
                    self.learned[name] = n / (t - first[0])
        if role == "input":
            self.last_ok[name] = t

    def on_estimate(self, est: Estimate) -> None:
        up = est.update
        if up is not None and up.accepted and est.sensor is not None:
            self.last_ok[est.sensor] = est.t

    def on_event(self, ev: Event) -> None:
        kind = ev.kind
        if kind in PROBLEMS and kind not in ("rejected", "malformed", "late"):  # those three are counters
            row = self.counts.setdefault(ev.sensor or "?", {})
            row[kind] = row.get(kind, 0) + 1
        if kind == "not_positive_definite":
            self._last_repair_t = ev.t
        elif kind == "reset":
            self._last_reset_t = ev.t

    # ------------------------------------------------------------------ reading
    def rates(self, t: float) -> dict[str, float]:
        """Hz by sensor over the last ``window_s`` s of sensor time before ``t`` (over the time since its
        first message while that is shorter)."""
        out = {}
        for name, times in self._times.items():
            while times and times[0] <= t - self.window_s:
                times.popleft()
            first = self._first.get(name, (t, 0))[0]
            span = min(self.window_s, t - first)
            out[name] = len(times) / span if span > 0.0 else math.nan
        return out

    def expected(self, name: str) -> float:
        return self.given_rate.get(name, self.learned.get(name, math.nan))

    def limit(self, name: str) -> float:
        if name in self.given_limit:
            return self.given_limit[name]
        rate = self.expected(name)
        return max(1.0, 10.0 / rate) if rate > 0.0 else math.inf

    def assess(self, t: float, rates: Mapping[str, float], counters: Mapping[str, Mapping[str, int]],
               source_state: str, *, silent_wall_s: float = 0.0, live: bool = False, estimate: Estimate | None = None,
               repairs: int = 0, resets: int = 0, message: str = "", rate_valid: bool = True) -> Health:
        """The health at sensor time ``t``. ``rates``: measured Hz by sensor (``rate_valid`` False when
        they are the run's mean, not a recent window); ``source_state``: the feed's state."""
        rows = []
        for name, role in self.roles.items():
            row = counters.get(name, {})
            counts = {k: int(row.get(k, 0)) for k in ("rejected", "malformed", "late")}
            counts.update({k: self.counts.get(name, {}).get(k, 0) for k in ("gap", "clock")})
            rate, expected, limit = rates.get(name, math.nan), self.expected(name), self.limit(name)
            last = self.last_ok.get(name)
            since = t - last if last is not None and t == t else math.nan
            if last is None:
                status = "waiting"
            elif since > limit:
                status = "stale"
            elif rate_valid and expected > 0.0 and rate == rate and rate < 0.5 * expected:
                status = "slow"
            else:
                status = "ok"
            rows.append(SensorHealth(name, role, rate, expected, since, limit, counts, status))
        clock = sum(c.get("clock", 0) for c in self.counts.values())
        state, reason = self._overall(rows, t, source_state, silent_wall_s, live, estimate, message)
        return Health(state, reason, tuple(rows), repairs, resets, clock)

    def _overall(self, rows: list[SensorHealth], t: float, source_state: str, silent_wall_s: float, live: bool,
                 estimate: Estimate | None, message: str) -> tuple[str, str]:
        if source_state == "lost":
            return "LOST", message or "source lost"
        if source_state == "reconnecting":
            return "LOST", message or "port lost; reconnecting"
        if live and source_state in ("running", "waiting") and silent_wall_s > self.silent_s:
            return "LOST", f"no data for {silent_wall_s:.0f} s"
        if estimate is not None and not (np.isfinite(estimate.belief.x).all() and np.isfinite(estimate.belief.sd).all()):
            return "LOST", "estimate not finite"
        started = [r for r in rows if r.status != "waiting"]
        if started and all(r.status == "stale" for r in started):
            worst = min(started, key=lambda r: r.since_ok)
            return "LOST", f"no sensor within its limit ({worst.name}: {worst.since_ok:.1f} s without an accepted one)"
        for r in rows:
            if r.status == "stale":
                return "DEGRADED", f"{r.name}: {r.since_ok:.1f} s without an accepted measurement (limit {r.limit:g} s)"
        for r in rows:
            if r.status == "slow":
                return "DEGRADED", f"{r.name}: {r.rate:.1f} Hz of {r.expected:.1f} expected"
        if t - self._last_repair_t <= self.recent_s:
            return "DEGRADED", f"covariance repaired at t = {self._last_repair_t:.3f} s"
        if t - self._last_reset_t <= self.recent_s:
            return "DEGRADED", f"filter reset at t = {self._last_reset_t:.3f} s"
        if not started:
            return "OK", "waiting for the first accepted measurement"
        return "OK", "every sensor within its rate and limit"
