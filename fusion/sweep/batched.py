"""The batched engine: the N seeds of one sweep variant advanced together by one batched filter
(fusion.batch), with the statistics of each trial kept by the pipeline's own ``RunStats`` (the same
``ErrorTracker``, truth interpolation, NEES and NIS code as ``fusion run``), so a row equals the row of
``fusion.pipeline.run`` on the same trial (tests/sweep/test_engines.py).

It mirrors ``fusion.scheduler.Scheduler`` for the systems where that is a short loop (:func:`unsupported`
says why a system is not one): measurement sensors only (no IMU input), messages in time order, the
configured initial belief, an estimate after every update and no fixed-rate outputs, no recovery, no
preprocessor, no smoother. The recordings of the seeds must be in lockstep (the same sensors, times and
bound models message by message: true of a simulated scenario whose timing has no random part);
otherwise :class:`NotLockstep` is raised and the engine runs those trials one by one through the pipeline.
"""
from __future__ import annotations

import copy
import time
from typing import Any

import numpy as np

from fusion.api import Estimate, MalformedMessage

from .trial import Trial, recording_of, row_of, system_of, with_initial

__all__ = ["unsupported", "run_batch", "NotLockstep"]


class NotLockstep(Exception):
    """The recordings of the seeds differ in their timing or content structure."""


def unsupported(system: Any, trial: Trial) -> str | None:
    """Why this trial cannot take the batched path (None when it can)."""
    from fusion.batch import batch_capable

    spec = system.spec
    if trial.smooth:
        return "the smoother runs through the pipeline"
    if not batch_capable(system.filter):
        return f"filter {system.filter.name!r} has no batched version"
    if getattr(system.filter, "_augmented", False):
        return "augmented ukf"
    p = getattr(system.filter, "params", None)
    if system.filter.name == "srukf" and (p.zeroth_point != "recentred" or p.covariance_update != "joint"):
        return "srukf variant without a batched version"
    if system.process.input_dim:
        return "an input sensor (IMU) drives the process"
    if spec.initial.from_sensor or spec.initial.align_s:
        return "initialisation from a sensor or by alignment"
    if spec.output.rate_hz or not spec.output.on_update:
        return "fixed-rate outputs"
    if spec.scheduler.late_policy != "drop":
        return "late_policy replay"
    for name, s in system.sensors.items():
        if s.preprocessor is not None or s.recovery is not None or s.time_offset:
            return f"sensor {name!r} has a preprocessor, recovery or time offset"
        if type(s.model).__dict__.get("pseudo_observation") is not None:
            return f"sensor {name!r} is a pseudo-measurement"
    return None


def _parse(system: Any, lines: list[str]) -> tuple[list[tuple], Any]:
    """Per message: ("truth", msg) or ("meas", sensor, obs); malformed lines are NotLockstep."""
    from fusion.logformat import ParsedStream, iter_messages

    parsed = ParsedStream()
    out: list[tuple] = []
    for item in iter_messages(lines, parsed):
        if isinstance(item, MalformedMessage):
            raise NotLockstep("a malformed line")
        if item.sensor in ("truth", "reference"):
            out.append((item.sensor, item))
            continue
        sensor = system.sensors.get(item.sensor)
        if sensor is None:
            raise NotLockstep(f"a sensor not in the config ({item.sensor})")
        try:
            dec = sensor.decoder.decode(item)
            obs = None if dec is None else sensor.model.observe(dec)
        except MalformedMessage:
            raise NotLockstep("a malformed message") from None
        if obs is None:
            continue
        if obs.R is not None:
            raise NotLockstep("an observation with its own R")
        out.append(("meas", sensor.name, obs))
    return out, parsed


def _signature(item: tuple) -> tuple:
    if item[0] == "meas":
        obs = item[2]
        return ("meas", item[1], obs.t, getattr(obs.model, "bound", id(type(obs.model))), obs.z.shape)
    return (item[0], item[1].t)


def run_batch(trials: list[Trial], timings: dict[str, float] | None = None) -> list[dict[str, Any]]:
    """Rows of the trials (one variant, different seeds) in the order given. Raises NotLockstep.
    ``timings`` (optional) gets the seconds spent wiring, simulating, parsing, in the filter math and in
    the statistics (summed over the trials)."""
    from fusion import pipeline
    from fusion.batch import make_batch_filter

    t0 = time.perf_counter()
    system = system_of(trials[0])                                # one variant: wired once
    systems = [system] * len(trials)                             # (each Run's Scheduler copies it)
    t1 = time.perf_counter()
    texts = [recording_of(tr) for tr in trials]
    t2 = time.perf_counter()
    streams = [_parse(system, lines) for lines in texts]
    t3 = time.perf_counter()
    sig = [_signature(it) for it in streams[0][0]]
    for items, _ in streams[1:]:
        if len(items) != len(sig) or any(_signature(it) != s for it, s in zip(items, sig)):
            raise NotLockstep("the seeds' recordings differ in timing or content")
    N = len(trials)
    systems = [with_initial(system, tr, lines) for tr, lines in zip(trials, texts)]   # drawn: own mean a seed
    x0s = np.stack([s.x0 for s in systems])
    runs = [pipeline.Run(s, hooks=False) for s in systems]         # their RunStats, Scheduler counters
    for r, (_, parsed) in zip(runs, streams):
        r.parsed.header = parsed.header
        r.stats.parsed = r.parsed
    bf = make_batch_filter(system.filter)
    process = system.process
    spec = system.spec
    max_predict = spec.scheduler.max_predict_s
    b = None
    steps = {"predict": 0, "update": 0}
    counts = {n: {"received": 0, "used": np.zeros(N, int), "rejected": np.zeros(N, int), "late": 0}
              for n in system.sensors}
    math_s = 0.0
    for k, s in enumerate(sig):
        if s[0] != "meas":
            for r, (items, _) in zip(runs, streams):
                comp = r.stats.comparison(items[k][0])
                if comp is not None:
                    comp.add_truth(items[k][1])
            continue
        name = s[1]
        obs0 = streams[0][0][k][2]
        sensor = system.sensors[name]
        c = counts[name]
        c["received"] += 1
        tm = time.perf_counter()
        if b is None:
            b = bf.initial_belief(obs0.t, x0s, system.P0)
        if obs0.t < b.t:
            c["late"] += 1
            continue
        if obs0.t - b.t > max_predict:                              # bounded prediction, as the scheduler
            b = copy.copy(b)
            b.t = obs0.t - max_predict
        dt = obs0.t - b.t
        if dt > 0.0:
            b = bf.predict(b, process, None, dt)
            steps["predict"] += 1
        z = np.stack([items[k][2].z for items, _ in streams])
        R = sensor.R
        m = z.shape[1]
        if R.shape[0] != m and m % R.shape[0] == 0:
            R = np.kron(np.eye(m // R.shape[0]), R)
        up = bf.update(b, obs0.model, z, R, sensor.gate)
        steps["update"] += 1
        b = up.belief
        math_s += time.perf_counter() - tm
        c["used"] += up.accepted
        c["rejected"] += ~up.accepted
        for i, r in enumerate(runs):
            st = r.stats
            st.add_nis(name, obs0.t, float(up.nis[i]), m)
            st.add_update(name, obs0.t, bool(up.accepted[i]))
            st.add_estimate(Estimate(obs0.t, b.belief(i), "update", name))
    rows = []
    share = (time.perf_counter() - t0 - math_s) / N
    for i, r in enumerate(runs):
        sched = r.scheduler
        sched.steps.update(steps)
        for n, c in counts.items():
            sc = sched.sensors[n].counters
            sc["received"] += c["received"]
            sc["used"] += int(c["used"][i])
            sc["rejected"] += int(c["rejected"][i])
            sc["late"] += c["late"]
        fc = sched.filter_counters      # the run's counts of the filter (fusion/scheduling/reporting.py)
        for key, v in bf.counters.items():
            if int(v[i]):
                fc[key] += int(v[i])
        r.stats.finish()
        summary = r.stats.summary("<lines>", 0.0)
        row = row_of(summary, [n for n, s in system.sensors.items() if s.role == "measurement"])
        row.update(status="ok", error="", engine="batch", wall_s=share + math_s / N)
        rows.append(row)
    if timings is not None:
        t4 = time.perf_counter()
        for k, v in (("wire", t1 - t0), ("simulate", t2 - t1), ("parse", t3 - t2), ("filter_math", math_s),
                     ("statistics", t4 - t3 - math_s)):
            timings[k] = timings.get(k, 0.0) + v
    return rows
