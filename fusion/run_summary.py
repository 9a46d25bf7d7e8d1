"""The summary of a run (DESIGN.md "Outputs"; what ``--summary-json`` writes), assembled from its
fusion.run_stats.RunStats: configuration, steps and their cost, per-sensor counters, errors against truth,
consistency, agreement with a reference, health, component info, events and the filter's counters."""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from fusion.run.stats import RunStats

__all__ = ["summary"]


def summary(stats: "RunStats", source: str, wall_s: float) -> dict[str, Any]:
    """The summary dict of a run: ``source`` its input's label, ``wall_s`` its wall time (s)."""
    system, sched = stats.system, stats.scheduler
    track = stats.tracker.summary()
    steps = dict(sched.steps)
    duration = (stats.t_last - stats.t_first) if stats.estimates else 0.0
    out: dict[str, Any] = {
        "config": str(system.path) if system.path else system.spec.name,
        "filter": system.filter.name,
        "input": str(source),
        "duration_s": duration,
        "wall_s": wall_s,
        "steps": steps,
        "us_per_predict": 1e6 * sched.time_s["predict"] / steps["predict"] if steps["predict"] else None,
        "us_per_update": 1e6 * sched.time_s["update"] / steps["update"] if steps["update"] else None,
        "sensors": stats.counters(),
    }
    if not stats.estimates:
        init = system.spec.initial
        why = (f"waiting for a first fix from {init.from_sensor!r} (initial.from_sensor)" if init.from_sensor
               else "no input reached the filter")
        counts = out["sensors"]
        mine = [counts.get(name, {}) for name in sched.sensors]
        if any(c.get("received", 0) for c in mine) and all(c.get("malformed", 0) == c.get("received", 0) for c in mine):
            why = "every message of the config's sensors was malformed: see the events for what failed on them"
        elif not any(c.get("received", 0) for c in mine):
            # the likeliest cause by far: a log of other sensors (or another config's), said in so many words
            why += f"; no message of the config's sensors ({', '.join(sched.sensors)}) was in the input"
            if sched.unused:
                why += f", which had {', '.join(sorted(sched.unused))}"
        failed = stats.update_failures()
        if failed:
            # the messages reached the filter and its measurement model failed on each (fusion.run.checks.Failures)
            told = "; ".join(f"{name}: {what} {n} time{'s' if n > 1 else ''}" for (name, _), (n, what) in failed.items())
            out["not_started"] = f"no estimate was made: every measurement that reached the filter was lost ({told})"
        else:
            out["not_started"] = f"no estimate was made: the filter was never initialised ({why})"
    if track.get("errors"):
        out["errors"] = track["errors"]
        if system.spec.evaluation.position:
            out["errors"]["position_elements"] = list(system.spec.evaluation.position)
    if track.get("consistency"):
        out["consistency"] = track["consistency"]
    if stats.reference is not None:
        agreement = stats.reference.tracker.summary()["errors"]
        if agreement:
            out["agreement"] = {"with": "reference (the onboard estimator's output in the log); "
                                            "an agreement, not an error", **agreement}
    out["health"] = stats.health()
    info = stats.component_info()
    if info:
        out["info"] = info
    if sched.unused:
        out["ignored_sensors"] = dict(sched.unused)
    if stats.events:
        out["events"] = dict(stats.events)
    counters = stats.filter_counters
    if counters:
        out["filter_counters"] = counters
    return out
