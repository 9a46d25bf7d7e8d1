"""The input integrator: the belief predicted through the input samples to a time, and the fixed-rate outputs on
the way. ``advance(belief, t)`` predicts with the held sample to ``t``; ``integrate(belief, samples, until)``
takes a run of input samples (one ``predict_inputs`` call for a filter that has it, PredictsInputRuns).
Each returns ``(belief, items)``: the belief and what it emits (``output`` estimates, events), in order.

A prediction that raises is the process model's fault when its own ``f``, ``Q`` or ``jacobian`` raises at the
belief (a ModelFault: the filter found what it returned unusable): the belief is held over the step, the first
failure reported, and :data:`PREDICT_FAILS_MAX` in a row stop the run with :class:`ProcessModelFailed`.
Otherwise the exception is the filter's own bug and raised again."""
from __future__ import annotations

import math
import time

import numpy as np

from fusion.api import Belief, Estimate, Event, FusionError, HoldsInput, Message, PredictsInputRuns, has
from fusion.errors import ModelFault
from fusion.run.checks import read_only, usable, who

__all__ = ["Integrator", "ProcessModelFailed", "PREDICT_FAILS_MAX"]

#: Predictions in a row that may fail (each holds the belief over its step, the first reported) before the run
#: stops with ProcessModelFailed: one odd input sample is not the end of a run, a process model that always
#: raises is.
PREDICT_FAILS_MAX = 5


class ProcessModelFailed(FusionError):
    """The process model (or the filter's prediction with it) raised on every prediction of
    :data:`PREDICT_FAILS_MAX` in a row: the belief cannot be carried on, so the run stops there (``fusion run``:
    exit 2, the summary of what was processed written)."""


class Integrator:
    """Predicts the belief through the input samples. ``u`` (and ``u_t``, its time, s): the input sample held;
    ``next_output``: the time of the next fixed-rate output (inf: none); ``quiet``: a replay's re-run (its
    outputs and events were emitted when it first ran). ``pseudo``: the after-predict pseudo-measurements,
    ``(plan, pseudo_observation)`` in config order; ``failures``: the run's fusion.run.checks.Failures."""

    def __init__(self, system, filt, process, tally, pseudo, failures, batch: bool):
        spec = system.spec
        self.registry = system.registry
        self.filter, self.process, self.tally, self.pseudo, self.failures = filt, process, tally, pseudo, failures
        self.max_predict = spec.scheduler.max_predict_s
        self.output_dt = 1.0 / spec.output.rate_hz if spec.output.rate_hz else None
        self.next_output = math.inf
        self.batch = batch and has(filt, PredictsInputRuns) and not pseudo
        # An input gap cut into several predictions by the other sensors: each is told how long the sample it
        # holds has been held already (fusion.api.HoldsInput), so the gap is one hold, not many.
        self.hold_after = process.hold_after if has(process, HoldsInput) else None
        self.u: np.ndarray | None = None
        self.u_t: float | None = None
        self.quiet = False
        self._fails = 0        # predictions failed in a row
        self.failed = 0        # predictions failed in the run

    def started(self, t: float) -> None:
        """The first belief was made at ``t`` (s): outputs from one period on."""
        self.next_output = t + self.output_dt if self.output_dt else math.inf

    def advance(self, belief: Belief, t: float) -> tuple[Belief, list]:
        """Predict with the held input to ``t``, emitting fixed-rate outputs on the way. A gap longer than
        ``max_predict_s`` is bounded: the belief is predicted over its last ``max_predict_s`` only (its
        uncertainty grows as over that time, not without bound) and a ``gap`` event says so."""
        items: list = []
        gap = t - belief.t
        if gap > self.max_predict:
            items.append(Event(t, "gap", None, f"{gap:.3f} s without a message; prediction bounded to the last "
                               f"{self.max_predict:g} s (scheduler.max_predict_s)"))
            belief = belief.with_(t=t - self.max_predict)
            if self.output_dt:
                k = math.ceil((belief.t - self.next_output) / self.output_dt)
                if k > 0:
                    self.next_output += k * self.output_dt
        tally = self.tally
        while self.next_output <= t:
            belief = self._step(belief, self.next_output)
            if tally:
                items += tally.take(self.quiet)
            if not self.quiet:
                items.append(Estimate(belief.t, belief, "output"))
            self.next_output += self.output_dt  # type: ignore[operator]
        belief = self._step(belief, t)
        if tally:
            items += tally.take(self.quiet)
        return belief, items

    def integrate(self, belief: Belief, good: list[tuple[float, np.ndarray]], until: float | None,
                  sensor: str) -> tuple[Belief, list]:
        """Integrate the samples ``good`` ((t s, u)) in order, the held sample up to each next one; with
        ``until`` (s), the last is held up to it in the same run."""
        items: list = []
        end = until if until is not None and until >= good[-1][0] else None
        last_t = good[-1][0] if end is None else end
        if (self.hold_after is not None and self.u_t is not None and belief.t > self.u_t
                and good[0][0] - self.u_t > self.hold_after):
            # the end of an input gap the other sensors cut into predictions: its last stretch is one more
            # prediction of the held sample at its age (_step), not a fresh hold in the run below
            belief, items = self.advance(belief, good[0][0])
        if self.batch and (len(good) > 1 or end is not None) and self.u is not None and self.next_output > last_t:
            belief, more = self._run(belief, good, end, last_t, sensor)
            items += more
            self.u, self.u_t = good[-1][1], good[-1][0]
            return belief, items
        for t, u in good:
            belief, more = self.advance(belief, t)
            items += more
            self.u, self.u_t = u, t
        return belief, items

    def _run(self, belief: Belief, good, end: float | None, last_t: float, sensor: str) -> tuple[Belief, list]:
        """The whole run of samples in one ``predict_inputs`` call (the filter integrates them in order: the
        same math). The intervals as floats (the same subtractions np.diff makes), the arrays built once for
        the samples kept (a zero interval, a repeated stamp, integrates nothing)."""
        items: list = []
        ts = [belief.t] + [t for t, _ in good] + ([end] if end is not None else [])
        ul = [self.u] + [u for _, u in (good if end is not None else good[:-1])]
        dl = [b - a for a, b in zip(ts, ts[1:])]
        top = max(dl)
        capped = top > self.max_predict
        if capped:
            items.append(Event(float(ts[-1]), "gap", sensor, f"{top:.3f} s between input samples; prediction "
                               f"bounded to {self.max_predict:g} s (scheduler.max_predict_s)"))
            dl = [d if d <= self.max_predict else self.max_predict for d in dl]
        if not all(d > 0 for d in dl):
            ul = [u for u, d in zip(ul, dl) if d > 0]
            dl = [d for d in dl if d > 0]
        if not dl:
            return belief, items
        t0 = time.perf_counter()
        k = len(dl)
        us, dts = np.array(ul, dtype=float), np.array(dl, dtype=float)
        try:
            predicted = self.filter.predict_inputs(belief, self.process, us, dts)
        except FusionError:
            raise
        except Exception as exc:   # as in _step: held over the run of samples
            belief = self._failed(belief, exc, last_t, us[0], float(dts[0]))
            predicted = None
        if predicted is not None:
            self._fails = 0
            self.tally.time_s["predict"] += time.perf_counter() - t0
            belief = self.tally.predicted(predicted, k, batched=k > 1, dts=dts)
            if capped:  # bounded gap: the run still ends at the last sample's time
                belief = belief.with_(t=last_t)
        if self.tally:
            items += self.tally.take(self.quiet)
        return belief, items

    def _step(self, belief: Belief, t: float) -> Belief:
        dt = t - belief.t
        if dt <= 0.0:
            return belief
        if self.process.input_dim and self.u is None:
            # no input sample yet: nothing to propagate with; hold the belief, move its time
            return belief.with_(t=t)
        t0 = time.perf_counter()
        process = self.process
        if self.hold_after is not None and self.u_t is not None:
            age = belief.t - self.u_t
            if age > 0.0 and age + dt > self.hold_after:
                process = process.held(age)  # type: ignore[attr-defined]
        try:
            predicted = self.filter.predict(belief, process, self.u, dt)
        except FusionError:
            raise
        except Exception as exc:  # a process model's f or Q that raises: see _failed
            return self._failed(belief, exc, t, self.u, dt)
        self._fails = 0
        self.tally.time_s["predict"] += time.perf_counter() - t0
        belief = self.tally.predicted(predicted, 1, dts=dt)
        if self.pseudo:
            belief = self._pseudo_updates(belief)
        return belief

    def _failed(self, belief: Belief, exc: Exception, t: float, u: np.ndarray | None, dt: float) -> Belief:
        """A prediction to ``t`` raised (see the module): the belief held over the step, or an exception."""
        if not isinstance(exc, ModelFault):
            x = read_only(belief.x)
            try:
                self.process.f(x, u, dt)
                self.process.Q(x, u, dt)
                self.process.jacobian(x, u, dt)
            except Exception as own:
                exc = own
            else:
                raise exc
        self._fails += 1
        self.failed += 1
        what = str(exc) if isinstance(exc, ModelFault) else f"{type(exc).__name__}: {exc}"
        why = f"process model {self.process.name!r} failed in a prediction: {what}"
        if self._fails >= PREDICT_FAILS_MAX:
            raise ProcessModelFailed(f"{why} ({self._fails} predictions in a row, at t = {t:.3f} s); the "
                                     "belief cannot be carried on") from exc
        if self.failed == 1:
            self.tally.add(Event(t, "warning", None, f"{why}; the belief is held over the step"))
        return belief.with_(t=t)

    def _pseudo_updates(self, belief: Belief) -> Belief:
        """The after-predict pseudo-measurements (fusion.api.PseudoMeasurement), in config order."""
        from fusion.run.measure import finite

        for plan, pseudo_observation in self.pseudo:
            sensor = plan.runtime
            obs = pseudo_observation(belief)
            if obs is None:
                continue
            checked = usable(obs)
            if type(checked) is str:
                name = who(sensor.model, self.registry, "measurement model")
                event = self.failures.lost(sensor, Message(belief.t, sensor.name, (), "-"), name,
                                           f"returned an unusable pseudo-observation: {checked}",
                                           f"returned an unusable pseudo-observation ({checked})")
                if event is not None:
                    self.tally.add(event)
                continue
            obs = checked
            R = obs.R if obs.R is not None else sensor.R
            try:
                result = self.filter.update(belief, obs.model, obs.z, R, plan.gate)
            except FusionError:
                raise
            except Exception as exc:
                event = self.failures.update_failed(sensor, obs.model, Message(belief.t, sensor.name, (), "-"),
                                                    exc, belief)
                if event is not None:
                    self.tally.add(event)
                continue
            self.tally.updated(result)
            if result.accepted and finite(result.nis, result.belief):
                belief = result.belief
                sensor.counters["used"] += 1
            else:
                sensor.counters["rejected"] += 1
        return belief
