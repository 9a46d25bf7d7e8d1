"""One released message through its sensor: an input sample to the integrator (fusion.run.integrator), a
measurement through its decoder, preprocessor and model to the measurement step (fusion.run.measure), before
the first belief to the start-up (fusion.run.startup). :class:`Processor` holds the run's belief; what it
yields are ``Estimate``, ``Event`` and ``Updated`` items, in order."""
from __future__ import annotations

import math
from typing import Iterator

import numpy as np

from fusion.api import Belief, Estimate, Event, Fix, MalformedMessage, Message, RejectedMessage
from fusion.run.checks import failed, shown, usable, who
from fusion.run.inputs import PendingInputs
from fusion.run.measure import Updated, measure
from fusion.run.plan import geometry_check

__all__ = ["Processor"]

_CHECK_EVERY_S = 0.5  # a model's geometry check runs at most this often per sensor, s of sensor time


class Processor:
    """The per-message path of a run (see the module). ``loop``: the parts it is given by fusion.run.loop.Loop
    (sensors, plans, integrator, start-up, tally, failures, replay log, filter)."""

    def __init__(self, loop):
        self.sensors, self.plans, self.filter = loop.sensors, loop.plans, loop.filter
        self.integrator, self.startup, self.tally, self.failures = (loop.integrator, loop.startup, loop.tally,
                                                                     loop.failures)
        self.replay, self.gates = loop.replay, loop.gates
        self.registry, self.layout = loop.system.registry, loop.system.layout
        self.input_dim = loop.process.input_dim
        self.on_update = loop.on_update
        self.pending = PendingInputs()
        self.belief: Belief | None = None
        self.replaying = False
        self.live = False
        self.resets = 0
        self._deferred: list = []
        self._warned: set[str] = set()  # sensors whose model's check() currently warns
        self._checked: dict[str, float] = {}  # sensor time of each sensor's last check()
        self._last_input_t: float | None = None
        self._last_u = None
        # the input sensor whose silence is reported while the other sensors go on (its max_gap)
        gaps = [(n, s.max_gap) for n, s in self.sensors.items() if s.role == "input" and s.max_gap is not None]
        self._input_gap = gaps[0] if gaps else None
        self._silence_told = False
        self._silence_last = -math.inf   # the input's last sample time when its silence was told

    # ------------------------------------------------------------------ replay's hooks
    def quiet(self, replaying: bool, live: bool) -> None:
        """A replay's re-run (``replaying``) reports nothing of the messages it re-runs, except of the late one
        itself (``live``)."""
        self.replaying, self.live = replaying, live
        self.integrator.quiet = replaying
        self.failures.quiet = replaying and not live

    def snapshot(self, rerun: bool = False) -> None:
        """Keep the belief after the messages logged so far (late_policy: replay); ``rerun``: also in a late
        message's re-run."""
        if self.replay is None or (self.replaying and not rerun) or self.belief is None:
            return
        ig = self.integrator
        self.replay.snapshot(self.belief, ig.u, ig.u_t, ig.next_output, self.gates)

    # ------------------------------------------------------------------ inputs
    def flush_inputs(self, until: float | None = None) -> Iterator:
        """Integrate the pending input samples; with ``until`` only those up to it (the last held to it), the
        later ones stay pending, so a measurement at ``until`` is applied at its own time."""
        batch = self.pending.take(until)
        if batch:
            yield from self._inputs(batch, until)

    def _inputs(self, msgs: list[Message], until: float | None = None) -> Iterator:
        """Input samples decoded and integrated in order (the held sample propagates up to each new one)."""
        sensor = self.sensors[msgs[0].sensor]
        good = []
        decode, input_from, max_gap = sensor.decoder.decode, self.integrator.process.input_from, sensor.max_gap
        for msg in msgs:
            try:
                decoded = decode(msg)
                if decoded is None:
                    sensor.counters["absorbed"] += 1
                    continue
                u = input_from(decoded)
            except MalformedMessage as exc:
                yield _bad(sensor, msg, exc)
                continue
            except Exception as exc:  # a plugin that fails on one message must not stop the run
                yield _bad(sensor, msg, failed(sensor.decoder, exc))
                continue
            t = msg.t
            last = self._last_input_t
            if max_gap is not None and last is not None and t - last > max_gap:
                if self._silence_told and t > self._silence_last:   # told while the others went on: it ends
                    yield Event(t, "resumed", msg.sensor, f"{msg.sensor} samples again after {t - last:.3f} s; "
                                "prediction held the last sample")
                else:                                               # one gap, one "gap" event
                    yield Event(t, "gap", msg.sensor, f"no {msg.sensor} sample for {t - last:.3f} s (limit "
                                f"{max_gap} s); prediction held the last sample")
            self._last_input_t = t
            if self._silence_told and t > self._silence_last:   # a new sample, not a held one
                self._silence_told = False
            good.append((t, u))
        if good:
            self._last_u = good[-1][1]
        if self.belief is None:
            n, i = self.startup.window(good, sensor.name)
            sensor.counters["used"] += n
            if i is None:
                return
            self._start(good[i][0])
            self.integrator.u, self.integrator.u_t = good[i][1], good[i][0]
            sensor.counters["used"] += 1
            good = good[i + 1:]
            for name in self.startup.aligners:   # aligned now: what the aligning models said about it
                yield from self.drain(name)
        if not good:
            return
        self.belief, items = self.integrator.integrate(self.belief, good, until, sensor.name)
        yield from items
        sensor.counters["used"] += len(good)
        self.snapshot()

    def _start(self, t: float) -> None:
        self.belief = self.startup.start(t)
        self.integrator.started(t)

    def belief_at(self, t: float) -> Belief | None:
        """The belief predicted to ``t`` with the inputs so far (for a ReadsBelief preprocessor), or None before
        the start; later than ``t`` when inputs past it are already integrated. What the prediction emits is
        handed on after the preprocessor's feed returns."""
        if self.belief is None:
            return None
        if self.pending:
            self._deferred.extend(self.flush_inputs(until=t))
        if self.belief.t < t:
            self.belief, items = self.integrator.advance(self.belief, t)
            self._deferred.extend(items)
        return self.belief

    def take_deferred(self) -> list:
        deferred, self._deferred = self._deferred, []
        return deferred

    def _input_silence(self, t: float, other: str) -> Iterator[Event]:
        """One ``gap`` event when the input has been silent for more than its max_gap at ``t`` (s), the time of
        another sensor's message: a sensor that dies is reported while the others go on."""
        name, max_gap = self._input_gap  # type: ignore[misc]
        last = self.pending.last_t if self.pending else self._last_input_t
        if last is not None and t - last > max_gap:
            self._silence_told, self._silence_last = True, last
            yield Event(t, "gap", name, f"no {name} sample for {t - last:.3f} s (limit {max_gap} s) while {other} "
                        "goes on; the prediction holds the last sample")

    # ------------------------------------------------------------------ measurements
    def process(self, msg: Message) -> Iterator:
        """One released message (recorded for a replay unless re-run)."""
        if self.replay is not None and not self.replaying:
            self.replay.record(msg)
        sensor = self.sensors[msg.sensor]
        if sensor.role == "input":
            yield from self._inputs([msg])
            return
        if self._input_gap is not None and not self._silence_told:
            yield from self._input_silence(msg.t, msg.sensor)
        plan = self.plans[msg.sensor]
        if plan.input_users or (self.belief is None and msg.sensor in self.startup.aligners):
            # the inputs up to this message first: a UsesInput component reads the latest sample, and an
            # aligning sensor's message must know whether the static start is over
            if self.pending:
                yield from self.flush_inputs(until=msg.t if self.belief is not None else None)
            for take_input in plan.input_users:
                take_input(self._last_input_t, self._last_u)
        try:
            decoded = sensor.decoder.decode(msg)
            if decoded is None:
                sensor.counters["absorbed"] += 1     # the decoder dropped it (fusion.run.stats.ABSORBED)
                return
            if type(decoded) is not Message and not isinstance(decoded, Message):
                raise MalformedMessage(f"{who(sensor.decoder, self.registry)} returned {shown(decoded)}, "
                                       "expected a fusion.api.Message or None")
            if sensor.preprocessor is None:
                outs = [decoded]
            else:                                    # held for a fix, or combined into the fix(es) it emits
                outs = sensor.preprocessor.feed(decoded)
                if type(outs) not in (list, tuple) or not all(isinstance(o, (Message, Fix)) for o in outs):
                    raise MalformedMessage(f"{who(sensor.preprocessor, self.registry)} feed returned "
                                           f"{shown(outs)}, expected a list of fusion.api.Message or Fix")
                sensor.counters["absorbed"] += 1 - len(outs)
        except MalformedMessage as exc:
            yield _bad(sensor, msg, exc)
            return
        except Exception as exc:  # a plugin that fails on one message must not stop the run
            yield _bad(sensor, msg, failed(sensor.preprocessor or sensor.decoder, exc, self.registry))
            return
        if self._deferred:                      # what a belief_at() call released (outputs, input events)
            yield from self.take_deferred()
        yield from self.drain(sensor.name)
        for out in outs:
            yield from self.measure(sensor, out)
        self.snapshot()

    def measure(self, sensor, msg: Message | Fix) -> Iterator:
        """A decoded message (or a solver's fix) of a measurement ``sensor``: observed, then the start-up's or
        the measurement step's."""
        try:
            obs = sensor.model.observe(msg)
        except MalformedMessage as exc:
            yield _bad(sensor, msg, exc)
            return
        except Exception as exc:  # a plugin that fails on one message must not stop the run
            yield _bad(sensor, msg, failed(sensor.model, exc, self.registry))
            return
        if obs is None:
            sensor.counters["absorbed"] += 1
            return
        checked = usable(obs)
        if type(checked) is str:   # the model's bug (it should raise MalformedMessage): lose this message
            event = self.failures.lost(sensor, msg, who(sensor.model, self.registry, "measurement model"),
                                       f"returned an unusable Observation: {checked}",
                                       f"returned an unusable Observation ({checked})")
            if event is not None:
                yield event
            return
        obs = checked
        if self.pending:
            yield from self.flush_inputs(until=obs.t)
        startup = self.startup
        if self.belief is None and startup.from_sensor == sensor.name:
            startup.take_fix(obs)
            sensor.counters["used"] += 1
            if not (startup.align_s or self.input_dim):
                self._start(obs.t)
            return
        if self.belief is None and sensor.name in startup.aligners:
            startup.aligners[sensor.name].append(obs)          # static observations for its align_state
            sensor.counters["used"] += 1
            return
        if self.belief is None and (not startup.have_fix or self.input_dim):
            sensor.counters["rejected"] += 1
            yield Event(obs.t, "rejected", sensor.name, "before the filter is initialised")
            return
        if self.belief is None:
            self._start(obs.t)
        if obs.t < self.belief.t:  # type: ignore[union-attr]
            # a fix stamped before the belief (a solver's cycle time): updating at the wrong time would bias
            # the estimate, so it is late like any other message
            sensor.counters["late"] += 1
            yield Event(obs.t, "late", sensor.name, f"observation {self.belief.t - obs.t:.3f} s older than the "  # type: ignore[union-attr]
                        "belief; dropped (stamp fixes at the closing message)")
            return
        self.belief, items = self.integrator.advance(self.belief, obs.t)  # type: ignore[arg-type]
        yield from items
        R = obs.R if obs.R is not None else sensor.R
        if R is None:
            yield _bad(sensor, msg, MalformedMessage(
                f"sensor {sensor.name!r} has no noise R in the config and its message carries none"))
            return
        if R.shape[0] != len(obs.z) and len(obs.z) % R.shape[0] == 0:
            R = _per_item(R, len(obs.z) // R.shape[0])   # R per item (a range) for a message of several
        yield from self._fused(sensor, msg, obs, R)

    def _fused(self, sensor, msg, obs, R) -> Iterator:
        """The measurement step's outcome handed on: counted, its events, the NIS and the estimate."""
        plan = self.plans[sensor.name]
        out = measure(self.filter, self.belief, obs, R, plan, self.layout, watch_on=not self.replaying)
        tally = self.tally
        tally.time_s["update"] += out.update_s
        tally.steps["update"] += len(out.results)
        for r in out.results:
            tally.updated(r)
        self.resets += out.resets
        self.belief = out.belief
        yield from out.events
        if out.failure is not None:
            event = self.failures.update_failed(sensor, obs.model, msg, out.failure, self.belief)
            if event is not None:
                yield event
            return
        if tally:
            yield from tally.take(self.replaying)
        for k, v in out.counts.items():
            sensor.counters[k] += v
        quiet = self.replaying and not self.live   # a re-run message: reported when it first ran
        result = out.result
        if out.verdict == "nonfinite":
            if not quiet:
                yield Event(obs.t, "rejected", sensor.name, f"model {obs.model.name!r}: the update is not finite "
                            f"(NIS {result.nis}: its prediction or Jacobian at this state is NaN or inf); the "
                            "belief is kept")
            return
        if quiet:
            return
        if out.verdict == "used":
            check = plan.check if obs.model is sensor.model else geometry_check(obs.model)
            if check is not None:
                yield from self._check(sensor.name, check)
        else:
            yield Event(obs.t, "rejected", sensor.name, f"NIS {result.nis:.1f} outside the gate")
        yield Updated(obs.t, sensor.name, result.nis, len(obs.z), result.accepted)
        if self.on_update:
            yield Estimate(obs.t, self.belief, "update", sensor.name, result)

    def _check(self, name: str, check) -> Iterator[Event]:
        """A model's geometry check (ChecksGeometry), reported when a warning starts and when it clears."""
        t = self.belief.t  # type: ignore[union-attr]
        if t - self._checked.get(name, -math.inf) < _CHECK_EVERY_S:
            return
        self._checked[name] = t
        events = check(self.belief, name)
        active = name in self._warned
        if events and not active:
            self._warned.add(name)
            yield from events
        elif not events and active:
            self._warned.discard(name)
            yield Event(t, "cleared", name, "the geometry warning no longer applies")

    def drain(self, name: str) -> Iterator[Event]:
        """The events the sensor's components queued since the last call (a solver's, a decoder's or model's
        ``take_events``)."""
        for take in self.plans[name].drainers:
            events = take()
            if events:
                yield from events

    def flushed(self, sensor) -> tuple[list | tuple, str | None]:
        """The preprocessor's ``flush()`` at the end of the input, checked as its ``feed`` is: ``(fixes, None)``,
        or ``((), why)`` when it raised or returned anything else (its held messages lost)."""
        pre = sensor.preprocessor
        try:
            outs = pre.flush()
        except Exception as exc:  # a plugin's failure at the end must not stop the run's end
            return (), (f"{who(pre, self.registry)} flush failed: {type(exc).__name__}: {exc}; the messages it held "
                        "are lost")
        if type(outs) not in (list, tuple) or not all(isinstance(o, (Message, Fix)) for o in outs):
            return (), (f"{who(pre, self.registry)} flush returned {shown(outs)}, expected a list of "
                        "fusion.api.Message or Fix; the messages it held are lost")
        return outs, None


def _bad(sensor, msg, exc: MalformedMessage) -> Event:
    """Count a message a plugin refused (rejected: outside the sensor's limits; else malformed)."""
    kind = "rejected" if isinstance(exc, RejectedMessage) else "malformed"
    sensor.counters[kind] += 1
    return Event(msg.t, kind, sensor.name, f"line {msg.line}: {exc}")


def _per_item(R: np.ndarray, k: int) -> np.ndarray:
    return np.kron(np.eye(k), R)
