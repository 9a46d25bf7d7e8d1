"""The scheduler's initialisation: the first belief from the configured one, a static-start alignment
(the process model's Aligns capability, then every AlignsState measurement model) and a first fix of
``initial.from_sensor`` (through the model's PositionFromFix capability when it has one). A mixin of
fusion.scheduler.Scheduler, whose attributes it uses."""
from __future__ import annotations

import math

import numpy as np

from fusion.api import Aligns, PositionFromFix, has
from fusion.config import SensorRuntime


class Initialisation:
    """Mixin: ``_start``, ``_align``, ``_take_fix``, ``_initial`` (see fusion.scheduler)."""

    def _start(self, t: float) -> None:
        """The first belief, at ``t``: the configured one, aligned and with the remembered fix if any."""
        belief = self.filter.initial_belief(t, *self._initial())
        if belief.events:   # a repaired initial covariance (srukf): reported with the first prediction's
            for e in belief.events:
                self.filter_counters[e.kind] += 1
            self._filter_events.extend(belief.events)
            belief = belief.with_(events=())
        self.belief = belief
        self._next_output = t + self.output_dt if self.output_dt else math.inf

    def _align(self, good: list[tuple[float, np.ndarray]], sensor: SensorRuntime) -> list[tuple[float, np.ndarray]]:
        """Before the first belief: gather the static start; create the belief once aligned (and fixed).
        Returns the samples left to integrate after the belief exists."""
        for i, (t, u) in enumerate(good):
            if self._align_t0 is None:
                self._align_t0 = t
            if t - self._align_t0 < self._align_s or not self._have_fix:
                self._align_u.append(u)
                sensor.counters["used"] += 1
                continue
            if self._align_s and self._align_u:
                u_mean = np.mean(self._align_u, axis=0)
                if has(self.process, Aligns):   # wiring refuses align_s for a process without it
                    self._x0, self._P0 = self.process.align(self._x0, self._P0, u_mean)
                for name, observations in self._aligners.items():
                    # called with no observations too (no sample of the sensor in the window): the model
                    # then knows the static start is over and can refuse its later messages with the reason
                    s = self.sensors[name]
                    self._x0, self._P0 = s.model.align_state(self._x0, self._P0, u_mean, observations, s.R)  # type: ignore[union-attr]
            self._start(t)
            self.u, self._u_t = u, t
            sensor.counters["used"] += 1
            return good[i + 1:]
        return []

    def _take_fix(self, obs) -> None:
        """Remember a fix of ``initial.from_sensor`` for the initial position (latest fix wins)."""
        self._fix = obs
        self._have_fix = True

    def _initial(self) -> tuple[np.ndarray, np.ndarray]:
        """x0, P0 with the position block from the remembered fix. A model with ``position_from`` (a
        position with a lever arm) turns the fix's position into the state's at the initial attitude.
        Values of the fix beyond the position (a GPS fix's velocity) set the state elements their rows of
        h select (a row of the model's analytic dh/dx that is a unit vector); rows that are not a plain
        selection, or a model without an analytic Jacobian, leave those elements to the first update."""
        x0, P0 = self._x0.copy(), self._P0.copy()
        obs = getattr(self, "_fix", None)
        if obs is None:
            return x0, P0
        sl = self.system.layout["p"]
        z = np.asarray(obs.z, dtype=float)
        k = min(len(z), sl.stop - sl.start)
        to_state = obs.model.position_from if has(obs.model, PositionFromFix) else None
        x0[sl.start:sl.start + k] = to_state(z, x0)[:k] if to_state else z[:k]
        rows, cols = list(range(k)), list(range(sl.start, sl.start + k))
        H = obs.model.jacobian(x0) if len(z) > k else None   # the model's analytic dh/dx (None: none)
        if H is not None:
            H = np.atleast_2d(H)
            for i in range(k, len(z)):
                j = int(np.argmax(np.abs(H[i])))
                if abs(H[i, j] - 1.0) < 1e-6 and np.sum(np.abs(H[i])) < 1.0 + 1e-6 and j not in cols:
                    x0[j] = z[i]
                    rows.append(i)
                    cols.append(j)
        if obs.R is not None:
            idx = np.array(cols)
            P0[idx, :] = 0.0
            P0[:, idx] = 0.0
            P0[np.ix_(idx, idx)] = np.asarray(obs.R)[np.ix_(rows, rows)]
        return x0, P0
