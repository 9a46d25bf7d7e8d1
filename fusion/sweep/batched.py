"""The batched engine: the N seeds of one sweep variant advanced together by one batched filter
(fusion.batch), reading the seeds' recordings as arrays (fusion.sweep.lockstep: simulated without the
text round-trip, the same numbers) and keeping each trial's statistics vectorised over steps and trials
(fusion.sweep.batchstats: the streaming rules of the pipeline's ``RunStats``; where it cannot reproduce
them, ``RunStats`` itself estimate by estimate), so a row equals the row of ``fusion.pipeline.run`` on
the same trial (tests/sweep/test_engines.py, test_batchstats.py).

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

from fusion.api import Estimate, KeepsGateState, has
from fusion.health import spec_of
from fusion.health.batch_watch import BatchHealthWatch

from . import batchstats
from .lockstep import NotLockstep, from_simulation
from .trial import Trial, health_columns, row_of, system_of, with_initial

__all__ = ["unsupported", "run_batch", "NotLockstep"]


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
    if system.filter.name == "srukf" and p.zeroth_point != "recentred":
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
        if s.gate is not None and has(s.gate, KeepsGateState):
            # the batch gates by threshold masks; a gate with per-run memory (reopening) decides otherwise
            return f"sensor {name!r}: gate {s.gate.name!r} keeps per-run state"
    return None


def run_batch(trials: list[Trial], timings: dict[str, float] | None = None) -> list[dict[str, Any]]:
    """Rows of the trials (one variant, different seeds) in the order given. Raises NotLockstep.
    ``timings`` (optional) gets the seconds spent wiring, making the recordings (simulating them and
    reading them as arrays, fusion.sweep.lockstep), in the filter math and in the statistics (summed
    over the trials)."""
    from fusion.batch import make_batch_filter

    t0 = time.perf_counter()
    system = system_of(trials[0])                                # one variant: wired once
    t1 = time.perf_counter()
    ls = from_simulation(system, trials)
    t3 = time.perf_counter()
    N = len(trials)
    first = ls.truth_v[:, 0] if (ls.truth_ok and ls.truth_t.size) else [None] * N
    if any(tr.initial == "drawn" for tr in trials) and not ls.truth_ok and ls.truth_t.size:
        raise NotLockstep("drawn initial means around truth the window would skip")
    systems = [with_initial(system, tr, truth=(ls.truth_names, None if f is None else tuple(f)))
               for tr, f in zip(trials, first)]                   # drawn: own mean a seed
    x0s = np.stack([s.x0 for s in systems])
    sensors = [n for n, s in system.sensors.items() if s.role == "measurement"]
    meas = [k for k, e in enumerate(ls.events) if e[0] == "meas"]
    why = None if ls.truth_ok or not ls.truth_t.size else "truth messages the window skips"
    if why is None:
        why = batchstats.unsupported(system, ls.truth_names, ls.truth_t,
                                     np.array([ls.events[k][2] for k in meas], float),
                                     np.array(meas, np.int64), ls.truth_idx)
    stats = _PerEstimate(systems, ls) if why else batchstats.BatchStats(
        system, N, ls.truth_names, ls.truth_t, ls.truth_v, ls.truth_idx, sensors)
    bf = make_batch_filter(system.filter)
    process = system.process
    max_predict = system.spec.scheduler.max_predict_s
    watch = BatchHealthWatch(system, N, spec_of(system))   # the health rule's records, per trial
    b = None
    steps = {"predict": 0, "update": 0}
    counts = {n: {"received": 0, "used": np.zeros(N, int), "rejected": np.zeros(N, int), "late": 0}
              for n in system.sensors}
    math_s = 0.0
    for k, ev in enumerate(ls.events):
        if ev[0] != "meas":
            if ev[0] == "truth" and why:
                stats.truth(ev[1])
            continue
        _, name, t, model, z = ev
        sensor = system.sensors[name]
        c = counts[name]
        c["received"] += 1
        tm = time.perf_counter()
        if b is None:
            b = bf.initial_belief(t, x0s, system.P0)
        if t < b.t:
            c["late"] += 1
            continue
        if t - b.t > max_predict:                                   # bounded prediction, as the scheduler
            b = copy.copy(b)
            b.t = t - max_predict
        dt = t - b.t
        if dt > 0.0:
            b = bf.predict(b, process, None, dt)
            steps["predict"] += 1
        R = sensor.R
        m = z.shape[1]
        if R.shape[0] != m and m % R.shape[0] == 0:
            R = np.kron(np.eye(m // R.shape[0]), R)
        up = bf.update(b, model, z, R, sensor.gate)
        steps["update"] += 1
        b = up.belief
        math_s += time.perf_counter() - tm
        c["used"] += up.accepted
        c["rejected"] += ~up.accepted
        stats.step(name, t, k, b, up, m)
        watch.add(name, t, up.accepted, up.nis, m)
    columns = stats.columns()
    rows = []
    share = (time.perf_counter() - t0 - math_s) / N
    for i in range(N):
        row = {"position_rmse_m": columns[i]["position_rmse_m"], "position_max_m": columns[i]["position_max_m"],
               "velocity_rmse_mps": columns[i]["velocity_rmse_mps"],
               "attitude_rmse_deg": columns[i]["attitude_rmse_deg"], "nees_mean": columns[i]["nees_mean"],
               "nees_in_95_fraction": columns[i]["nees_in_95_fraction"], "estimates": columns[i]["estimates"],
               "updates": steps["update"],
               "rejected": sum(int(c["rejected"][i]) for c in counts.values()),
               "late": sum(c["late"] for c in counts.values()), "malformed": 0, "resets": 0,
               "not_positive_definite": int(bf.counters.get("not_positive_definite", np.zeros(N, int))[i])}
        for s in sensors:
            row[f"nis_mean_{s}"] = columns[i][f"nis_mean_{s}"]
        row.update(_health(systems[i], counts, i, row, getattr(stats, "dof", None), watch.report(i)))
        row.update(status="ok", error="", engine="batch", wall_s=share + math_s / N)
        rows.append(row)
    if timings is not None:
        t4 = time.perf_counter()
        for key, v in (("wire", t1 - t0), ("recordings", t3 - t1), ("filter_math", math_s),
                       ("statistics", t4 - t3 - math_s)):
            timings[key] = timings.get(key, 0.0) + v
    return rows


def _health(system: Any, counts: dict, i: int, row: dict[str, Any], nees_dof: int | None,
            watch: dict[str, Any]) -> dict[str, Any]:
    """Trial ``i``'s health columns (fusion.sweep.trial.health_columns) from its counters, errors and its
    report of the batch's health watch (fusion.health.batch_watch)."""
    sensors = {n: {"received": c["received"], "used": int(c["used"][i]), "rejected": int(c["rejected"][i]),
                   "late": c["late"], "malformed": 0} for n, c in counts.items()}
    errors = {k: row[k] for k in ("position_rmse_m", "position_max_m", "velocity_rmse_mps") if k in row}
    summary = {"sensors": sensors, "errors": errors,
               "consistency": {"nees_mean": row.get("nees_mean"), "nees_dof": nees_dof,
                               "nees_in_95_fraction": row.get("nees_in_95_fraction")}}
    return health_columns(system, summary, watch)


class _PerEstimate:
    """The statistics through the pipeline's own RunStats, estimate by estimate (the cases
    fusion.sweep.batchstats does not reproduce; :func:`fusion.sweep.batchstats.unsupported`)."""

    def __init__(self, systems: list, ls: Any):
        from fusion import pipeline

        self.ls = ls
        self.runs = [pipeline.Run(s, hooks=False) for s in systems]
        for r, h in zip(self.runs, ls.headers):
            r.parsed.header = h
            r.stats.parsed = r.parsed

    def truth(self, j: int) -> None:
        for i, r in enumerate(self.runs):
            comp = r.stats.comparison("truth")
            if comp is not None:
                comp.add_truth(self.ls.truth_message(i, j))

    def step(self, name: str, t: float, k: int, b: Any, up: Any, m: int) -> None:
        for i, r in enumerate(self.runs):
            st = r.stats
            st.add_nis(name, t, float(up.nis[i]), m)
            st.add_update(name, t, bool(up.accepted[i]))
            st.add_estimate(Estimate(t, b.belief(i), "update", name))

    def columns(self) -> list[dict[str, Any]]:
        out = []
        for r in self.runs:
            r.stats.finish()
            summary = r.stats.summary("<lines>", 0.0)
            sensors = [n for n, s in r.system.sensors.items() if s.role == "measurement"]
            out.append(row_of(summary, sensors))
        return out
