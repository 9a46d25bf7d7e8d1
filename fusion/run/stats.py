"""What a run counts, accumulated online in constant memory: :class:`RunStats` (owned by one
fusion.run.session.Run). Its summary dict is assembled by fusion.run_summary."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from fusion.api import Estimate, Event
from fusion.config import System
from fusion.logformat import ParsedStream
from fusion.metrics import ErrorTracker
from fusion.run_summary import summary
from fusion.truth_stream import TruthComparison

if TYPE_CHECKING:
    from fusion.run.loop import Loop

__all__ = ["RunStats", "COUNTERS", "ABSORBED"]

COUNTERS = ("received", "used", "rejected", "malformed", "late")
#: Messages of a sensor that its decoder or preprocessor took without a measurement of their own coming
#: out: a decoder's None (a sentence without a fix, a message it drops), a model's ``observe`` returning
#: None, and the messages a solver (preprocessor) combined into a fix, the fix itself counted once as
#: used, rejected, malformed or late (ols_trilateration: the 3-4 ranges of a firing cycle are one fix),
#: or still held when the input ended. So received = used + rejected + malformed + late + absorbed. In
#: the summary JSON for every sensor; the human table shows its column only when some sensor has any.
ABSORBED = "absorbed"
_NIS_WAIT_MAX = 4096  # NIS records held until the first estimate starts the settle clock


class RunStats:
    """Everything a run counts, accumulated online in constant memory (owned by one run).

    Counters per sensor (the scheduler's, plus malformed lines of sensors the config does not have),
    events by kind, step counts and times, errors against ``truth`` lines and agreement with
    ``reference`` lines (``fusion.metrics.ErrorTracker`` fed through ``fusion.truth_stream``), NEES, NIS,
    and the span and health of the estimates."""

    def __init__(self, system: System, scheduler: Loop, parsed: ParsedStream):
        self.system = system
        self.scheduler = scheduler
        self.parsed = parsed
        ev = system.spec.evaluation
        self._settle_s, self._position = ev.settle_s, ev.position
        self.tracker = ErrorTracker(system.layout, None, settle_s=ev.settle_s, position=ev.position,
                                    keep_nis_series=False)
        self.truth: TruthComparison | None = None
        self.reference: TruthComparison | None = None
        self.events: dict[str, int] = {}
        self.estimates = 0
        self.t_first = math.inf
        self.t_last = -math.inf
        self.nonfinite = 0        # estimates with a non-finite mean or sd
        self.largest_sd = 0.0     # over the run, any element
        self._nis_wait: list[tuple[str, float, float, int, bool | None]] | None = []
        self.diverged_s = 0.0     # sensor time from a non-finite estimate to the next estimate
        self._last_nonfinite = False
        self._last_t = math.nan
        self.last_finite = True   # the last estimate of the run is finite
        self._updates: dict[str, list[float]] = {}  # sensor -> [first update t, last accepted t, longest gap]
        self._rejected_runs: dict[str, list] = {}   # sensor -> see add_update
        self.on_result: Callable | None = None  # (estimate, errors, truth_row) for a plot

    # ------------------------------------------------------------------ feeding
    def comparison(self, stream: str) -> TruthComparison | None:
        """The comparison against ``truth`` or ``reference``, created once the log header names its
        fields (None until then)."""
        current = self.truth if stream == "truth" else self.reference
        if current is not None:
            return current
        names = self.parsed.header.fields.get(stream)
        if not names:
            return None
        if stream == "truth":
            self.truth = TruthComparison(self.tracker, names, on_result=self.on_result)
            return self.truth
        tracker = ErrorTracker(self.system.layout, None, settle_s=self._settle_s, position=self._position,
                               keep_nis_series=False)
        if self.t_first < math.inf:
            tracker.start(self.t_first)
        self.reference = TruthComparison(tracker, names)
        return self.reference

    def add_estimate(self, est: Estimate) -> None:
        t = est.t
        if self.estimates == 0:
            self.tracker.start(t)
            self._release_nis()
            self.comparison("truth")
            if self.reference is not None:
                self.reference.tracker.start(t)
        self.estimates += 1
        if t < self.t_first:
            self.t_first = t
        if t > self.t_last:
            self.t_last = t
        sd = est.belief.sd
        top = float(sd.max()) if sd.size else 0.0
        if self._last_nonfinite and t > self._last_t:
            self.diverged_s += t - self._last_t
        if top != top or top == math.inf or not np.isfinite(est.belief.x).all():
            self.nonfinite += 1
            self._last_nonfinite = True
        else:
            self._last_nonfinite = False
            if top > self.largest_sd:
                self.largest_sd = top
        self.last_finite = not self._last_nonfinite
        self._last_t = t
        if self.truth is not None:
            self.truth.add_estimate(est)
        elif self.on_result is not None:
            self.on_result(est, None, None)
        if self.reference is not None:
            self.reference.add_estimate(est)

    def add_nis(self, sensor: str, t: float, nis: float, dim: int, accepted: bool | None = None) -> None:
        wait = self._nis_wait
        if wait is not None:
            wait.append((sensor, t, nis, dim, accepted))
            if len(wait) > _NIS_WAIT_MAX:  # no estimate is coming (outputs off): start the clock here
                self.tracker.start(wait[0][1])
                self._release_nis()
            return
        self.tracker.add_nis(sensor, nis, dim, t=t, accepted=accepted)

    def _release_nis(self) -> None:
        wait, self._nis_wait = self._nis_wait, None
        for sensor, t, nis, dim, accepted in wait or ():
            self.tracker.add_nis(sensor, nis, dim, t=t, accepted=accepted)

    def add_update(self, sensor: str, t: float, accepted: bool) -> None:
        """One update of ``sensor`` at ``t``: tracks the longest time without an accepted one and the longest
        run of updates rejected in a row (a lock-out, tester5 #1)."""
        u = self._updates.get(sensor)
        if u is None:
            u = self._updates[sensor] = [t, math.nan, 0.0, t]
            self._rejected_runs[sensor] = [math.nan, 0, math.nan, 0, 0.0]
        u[3] = t
        r = self._rejected_runs[sensor]   # [run start t, run count, longest run's start, its count, its span s]
        if accepted:
            since = u[1] if u[1] == u[1] else u[0]
            u[2] = max(u[2], t - since)
            u[1] = t
            r[0], r[1] = math.nan, 0
            return
        if r[1] == 0:
            r[0] = t
        r[1] += 1
        if r[1] > r[3] or (r[1] == r[3] and t - r[0] > r[4]):
            r[2], r[3], r[4] = r[0], r[1], t - r[0]

    def lockouts(self) -> dict[str, dict[str, float]]:
        """The sensors whose updates were all rejected for at least their recovery's ``after_s`` and
        ``min_rejected`` (the recovery's defaults, 2 s and 3, for a sensor without one), reset or not:
        ``{sensor: {"rejected": n, "from_s": t, "for_s": s}}`` of the longest run (in updates)."""
        from fusion.recovery import RecoverySpec

        out = {}
        for sensor, (_, _, start, n, span) in sorted(self._rejected_runs.items()):
            runtime = self.scheduler.sensors.get(sensor)
            spec = (runtime.recovery if runtime is not None else None) or RecoverySpec()
            if n >= spec.min_rejected and span >= spec.after_s:
                out[sensor] = {"rejected": n, "from_s": start, "for_s": span}
        return out

    def health(self) -> dict[str, Any]:
        """The summary's ``health``: non-finite estimates, the largest sd, time diverged, the longest time
        without an accepted measurement per sensor (from its first update, up to its last), resets and
        clock events. ``rejected_in_a_row`` ({sensor: the longest run of its updates rejected in a row}) and
        ``locked_out`` (:meth:`lockouts`: such runs as long as a lock-out, whether the recovery fired or
        not: a stretch of bad measurements, a disturbed magnetic field, or a filter locked out of good
        ones) say when a sensor was shut out for long; ``alignment_not_static`` (the numbers) when the
        static start was judged moving."""
        longest = {}
        for sensor, (first, last_ok, gap, last) in sorted(self._updates.items()):
            tail = last - (last_ok if last_ok == last_ok else first)
            longest[sensor] = max(gap, tail)
        out = {"nonfinite_estimates": self.nonfinite, "final_estimate_finite": self.last_finite,
               "largest_sd": self.largest_sd, "diverged_s": self.diverged_s,
               "longest_without_accepted_s": longest, "resets": self.scheduler.resets,
               "clock_events": self.events.get("clock", 0),
               "rejected_in_a_row": {k: r[3] for k, r in sorted(self._rejected_runs.items())},
               "locked_out": self.lockouts()}
        why = self.scheduler.alignment_not_static
        if why:   # only then: a static start's summary is unchanged
            out["alignment_not_static"] = why
        return out

    def add_event(self, event: Event) -> None:
        self.events[event.kind] = self.events.get(event.kind, 0) + 1

    def finish(self) -> None:
        self._release_nis()
        for comp in (self.truth, self.reference):
            if comp is not None:
                comp.finish()

    # ------------------------------------------------------------------ reading
    def counters(self) -> dict[str, dict[str, int]]:
        """Per sensor: received, used, rejected, malformed, late and absorbed (:data:`ABSORBED`). Malformed
        lines of configured sensors are counted by the scheduler, the others (unknown or unreadable sensor:
        '?') by the parser."""
        out = {name: dict(s.counters) for name, s in self.scheduler.sensors.items()}
        for c in out.values():
            if c.get(ABSORBED, 0) < 0:   # a solver that made more fixes than it was given messages
                c[ABSORBED] = 0
        for name, n in list(self.parsed.malformed.items()):
            if name not in self.scheduler.sensors:
                row = out.setdefault(name or "?", dict.fromkeys((*COUNTERS, ABSORBED), 0))
                row["received"] += n
                row["malformed"] += n
        return out

    def component_info(self) -> dict[str, dict[str, Any]]:
        """``{sensor: {kind: info}}`` of the components that report something (fusion.api.ReportsInfo)."""
        from fusion.api import ReportsInfo

        out: dict[str, dict[str, Any]] = {}
        for name, s in self.scheduler.sensors.items():
            for comp in (s.decoder, s.preprocessor, s.model):
                if comp is not None and isinstance(comp, ReportsInfo):
                    out.setdefault(name, {})[comp.kind] = comp.info()
        return out

    def ignored(self) -> dict[str, int]:
        """Messages of sensors the config does not have, by sensor name."""
        return dict(self.scheduler.unused)

    @property
    def filter_counters(self) -> dict[str, int]:
        """The filter's diagnostics for this run (``predicts``, ``not_positive_definite``, ...), counted by
        the scheduler from what the filter returned (filters keep no counters)."""
        return dict(self.scheduler.filter_counters)

    @property
    def gate_counters(self) -> dict[str, dict[str, int]]:
        """Per gated sensor, its gate's decisions this run (``checked``, ``rejected``, and reasons such as the
        ``reopening`` gate's ``opened``), counted by the run (gates keep nothing: fusion.api.GateRun)."""
        return self.scheduler.gate_counters

    def update_failures(self) -> dict[tuple[str, str], list]:
        """Per (sensor, component): [messages lost to its failure in an update, the first reason]."""
        return dict(self.scheduler.update_failures)

    def summary(self, source: str, wall_s: float) -> dict[str, Any]:
        """The summary dict of DESIGN.md "Outputs" (fusion.run_summary)."""
        return summary(self, source, wall_s)
