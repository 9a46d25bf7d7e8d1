"""What the run checks of what a plugin hands it on a message, so a plugin's bug loses that message
(counted malformed, the plugin named) instead of the run: a measurement model's Observation
(:func:`usable`), a gate's decision (:class:`CheckedGateRun`, whose failure is :class:`GateFailed`), and how a
component is named in those reports (:func:`who`: with its package when it is a third party's)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from fusion.api import Event, Fix, GateDecision, GateRun, MalformedMessage, Message, Observation
from fusion.errors import ModelFault
from fusion.lapack import lapack

__all__ = ["who", "shown", "GateFailed", "CheckedGateRun", "usable", "Failures", "model_fault", "read_only", "failed"]


def who(component, registry=None, kind: str | None = None) -> str:
    """``kind 'name'`` of a component (``kind`` given: e.g. "measurement model"), with its package when it is a
    third party's and ``registry`` knows it: ``gate 'patient' (fusion-gates 0.1.0)``."""
    if component is None:
        return "a plugin"
    label = f"{kind or component.kind} {getattr(component, 'name', type(component).__name__)!r}"
    if registry is not None and hasattr(registry, "provider_of"):
        provider = registry.provider_of(type(component))
        if not provider.endswith("(built-in)"):
            label += f" ({provider})"
    return label


def shown(value) -> str:
    """A plugin's wrong return value, briefly: its repr (cut at 60 characters) and its type."""
    text = repr(value)
    return f"{text[:57] + '...' if len(text) > 60 else text} ({type(value).__name__})"


class GateFailed(Exception):
    """A gate's ``check`` raised, or returned something else than ``(GateDecision, next state)``: the gate's
    fault, so the run loses that message (naming the gate) instead of ending the run."""

    def __init__(self, gate, why: str):
        super().__init__(why)
        self.gate = gate


class CheckedGateRun(GateRun):
    """The run's :class:`fusion.api.GateRun`: a gate that fails on a measurement raises
    :class:`GateFailed` through the filter's update (the state and counts unchanged)."""

    __slots__ = ()

    def accept(self, nis: float, dim: int) -> bool:
        try:
            out = self.gate.check(nis, dim, self.state)
        except Exception as exc:
            raise GateFailed(self.gate, f"{type(exc).__name__}: {exc}") from exc
        if type(out) is not tuple or len(out) != 2 or not isinstance(out[0], GateDecision):
            raise GateFailed(self.gate, f"check returned {shown(out)}, expected (GateDecision, next state)")
        decision, state = out
        reasons = decision.reasons
        if not isinstance(decision.accepted, (bool, np.bool_)) or not isinstance(reasons, (tuple, list)):
            raise GateFailed(self.gate, f"check returned {decision!r}, expected accepted a bool and reasons a tuple "
                                         "of counter names")
        self.state = state
        self.last = decision
        c = self.counters
        c["checked"] += 1
        if not decision.accepted:
            c["rejected"] += 1
        for reason in reasons:
            c[reason] += 1
        return bool(decision.accepted)


def usable(obs) -> Observation | str:
    """``obs`` (what a model's ``observe`` returned) as a filter can use it (``z`` and ``R`` as float arrays when a model gave lists), or why it
    cannot be used: not an Observation, a time that is no finite number (s), ``z`` not of shape ``(dim,)``
    (its model's) or not finite, an ``R`` not ``(dim, dim)``, not finite, not symmetric or not positive
    definite. The sums run on Python floats (``tolist``): ~0.3 us against ~1.5 us for a numpy reduction of
    a few values, so the whole check costs ~1 us an observation (~3 us with an R of several values)."""
    if not isinstance(obs, Observation):
        return f"it is {shown(obs)}, not a fusion.api.Observation (or None)"
    t = obs.t
    try:
        finite = math.isfinite(t)
    except TypeError:
        return f"its time t = {t!r} is not a number (s)"
    if not finite:
        return f"its time t = {t!r} is not finite (s)"
    try:
        z, R = obs.z, obs.R
        if type(z) is not np.ndarray or (R is not None and type(R) is not np.ndarray):
            z = np.asarray(z, dtype=float)
            R = None if R is None else np.asarray(R, dtype=float)
            obs = dataclasses.replace(obs, z=z, R=R)
        m = int(obs.model.dim)
        if z.shape != (m,):
            return f"its z has shape {z.shape}, expected ({m},) (its model's dim)"
        values = z.tolist()
        total = sum(values)          # a NaN or inf propagates (an overflow of finite values is told apart)
        if total - total != 0.0 and not all(map(math.isfinite, values)):
            return f"its z = {values} is not finite"
        if R is None:
            return obs
        if R.shape != (m, m):
            return f"its R has shape {R.shape}, expected ({m}, {m})"
        rows = R.tolist()
        if m == 1:
            if not 0.0 < rows[0][0] < math.inf:
                return f"its R = {rows} is not a positive finite variance"
            return obs
        total = sum(map(sum, rows))
        if total - total != 0.0 and not all(math.isfinite(v) for row in rows for v in row):
            return f"its R holds NaN or inf: {rows}"
        for i in range(1, m):        # the mirror, by index (a few values; a rounding's asymmetry is let by)
            for j in range(i):
                a, b = rows[i][j], rows[j][i]
                if a != b and abs(a - b) > 1e-9 * max(abs(a), abs(b), abs(rows[i][i]), abs(rows[j][j])):
                    return f"its R is not symmetric: {rows}"
        if lapack.dpotrf(R, lower=1)[1] != 0:   # np.linalg.cholesky's test, ~5x cheaper
            return f"its R is not positive definite: {rows}"
    except Exception as exc:   # a t or an array of things that are not numbers
        return f"it cannot be read: {type(exc).__name__}: {exc}"
    return obs


def failed(component, exc: Exception, registry=None) -> MalformedMessage:
    """A plugin's unexpected exception on one message, as the reason that message is malformed (the plugin
    should raise MalformedMessage itself; the run goes on either way)."""
    return MalformedMessage(f"{who(component, registry)} failed on it: {type(exc).__name__}: {exc}")


class Failures:
    """The messages lost to a plugin's failure on them (a model's ``h`` or ``jacobian`` raising in the update, a
    gate's ``check``, an unusable Observation): per (sensor, component) ``[count, first reason]``. The first of
    each is reported, the others counted and their number told at the end (``warnings``). ``quiet``: a replay's
    re-run (counted and told when it first ran)."""

    def __init__(self, registry=None):
        self.registry = registry
        self.by: dict[tuple[str, str], list] = {}
        self.quiet = False

    def lost(self, sensor, msg: Message | Fix, name: str, what: str, short: str) -> Event | None:
        """A message of ``sensor`` (its SensorRuntime) lost to ``name``'s failure on it (``what``): counted
        malformed; the event of the first of each sensor and component, else None."""
        sensor.counters["malformed"] += 1
        if self.quiet:
            return None
        failures = self.by.get((sensor.name, name))
        if failures is not None:
            failures[0] += 1
            return None
        self.by[(sensor.name, name)] = [1, f"{name} {short}"]
        return Event(msg.t, "malformed", sensor.name, f"line {msg.line}: {name} {what}; the message is lost, the "
                     f"belief kept (further failures of {sensor.name} are counted)")

    def update_failed(self, sensor, model, msg: Message, exc: Exception, belief) -> Event | None:
        """An update of ``sensor`` raised. When its gate is at fault (GateFailed) or its model is (its ``h`` or
        ``jacobian`` raises at the ``belief``, or ``h`` returns another shape than ``(dim,)``), the message is lost
        (:meth:`lost`). Otherwise it is the filter's own bug: ``exc`` is raised again (an internal error)."""
        if isinstance(exc, GateFailed):
            name = who(exc.gate, self.registry)
            return self.lost(sensor, msg, name, f"failed in the update: {exc}", f"failed in an update ({exc})")
        error = str(exc) if isinstance(exc, ModelFault) else model_fault(model, read_only(belief.x))
        if error is None:
            raise exc
        name = who(model, self.registry, "measurement model")
        return self.lost(sensor, msg, name, f"failed in the update: {error}", f"failed in an update ({error})")

    def warnings(self) -> list[Event]:
        """At the end: one warning per sensor and component that failed more than once."""
        return [Event(math.nan, "warning", name, f"{why} {n} times, each message lost (counted malformed)")
                for (name, _), (n, why) in self.by.items() if n > 1]


def model_fault(model, x: np.ndarray) -> str | None:
    """Why a measurement model fails at the state ``x`` (n,) and on a batch of two (what a filter gives it): its
    ``h`` or ``jacobian`` raises (the exception), or ``h`` returns another shape than ``(dim,)`` / ``(2, dim)``;
    None when it does neither there (an update that failed anyway is the filter's bug)."""
    try:
        dim = int(model.dim)
        one, two = np.shape(model.h(x)), np.shape(model.h(np.stack([x, x])))
        if one != (dim,) or two != (2, dim):
            return f"h returned shape {one} at the belief ({two} on 2 states), expected ({dim},) ((2, {dim}))"
        model.jacobian(x)
    except Exception as exc:
        return f"{type(exc).__name__}: {exc}"
    return None


def read_only(x: np.ndarray) -> np.ndarray:
    """A read-only view of the belief's mean for a model probed after a failure (one that writes into it raises)."""
    v = x.view()
    v.flags.writeable = False
    return v
