"""``fusion run CONFIG``: replay a recording through the configured estimator and report."""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from fusion.api import ConfigError, Estimate, Event, FusionError
from fusion.config import System, load_system
from fusion.yamlsource import load_yaml
from fusion.logformat import ParsedStream, iter_messages
from fusion.overrides import filter_override
from fusion.scheduler import Scheduler
from fusion.sources.recording import open_lines


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="replay a recording through a config and print a summary",
                       description="Replay a recording (the config's own, or --input) through the estimator the "
                                   "config composes; print a summary with errors against truth when the recording "
                                   "has truth lines.")
    p.add_argument("config", help="system YAML (e.g. configs/abps_ins.yaml)")
    p.add_argument("--input", "-i", metavar="LOG", help="recording to replay instead of the config's own ('-' for stdin)")
    p.add_argument("--filter", metavar="NAME", help="use this filter instead of the config's (kf, ekf, iekf, ukf, srukf)")
    p.add_argument("--filter-param", metavar="KEY=VALUE", action="append", default=[],
                   help="set a filter parameter (repeatable; VALUE is YAML, e.g. alpha=0.5)")
    p.add_argument("--output", "-o", metavar="PATH", help="write estimates as CSV (.csv) or JSON Lines (.jsonl)")
    p.add_argument("--summary-json", metavar="PATH", help="write the summary as JSON")
    p.add_argument("--plot", metavar="PATH.png", help="plot trajectory, errors with 3-sigma bounds and NIS")
    p.add_argument("--quiet", "-q", action="store_true", help="no table on stdout")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def replay(system: System, source: str | Path, on_estimate=None, on_event=None, progress=None) -> dict[str, Any]:
    """Run the system over a recording; returns the raw results (estimates, scheduler, parse state)."""
    parsed = ParsedStream()
    scheduler = Scheduler(system)
    estimates: list[Estimate] = []
    events: dict[str, int] = {}
    last_t = math.nan
    wall0 = time.perf_counter()
    try:
        for item in scheduler.run(iter_messages(open_lines(source), parsed)):
            if isinstance(item, Estimate):
                estimates.append(item)
                last_t = item.t
                if on_estimate:
                    on_estimate(item)
                if progress is not None:
                    progress(item.t)
            else:
                events[item.kind] = events.get(item.kind, 0) + 1
                if on_event:
                    on_event(item)
    except FusionError:
        raise
    except Exception as exc:
        where = f"t = {last_t:.3f} s" if math.isfinite(last_t) else "the start"
        raise RuntimeError(f"{exc} (the run got as far as {where}, {len(estimates)} estimates)") from exc
    return {"estimates": estimates, "scheduler": scheduler, "parsed": parsed, "events": events,
            "wall_s": time.perf_counter() - wall0}


def summarize(system: System, source: str | Path, result: dict[str, Any]) -> dict[str, Any]:
    """The summary dict of DESIGN.md "Outputs"."""
    from fusion.metrics import ErrorTracker, Truth

    sched: Scheduler = result["scheduler"]
    parsed: ParsedStream = result["parsed"]
    estimates: list[Estimate] = result["estimates"]
    truth = None
    names = parsed.header.fields.get("truth")
    if sched.truth and names:
        truth = Truth.from_messages(sched.truth, names)
    ev = system.spec.evaluation
    tracker = ErrorTracker(system.layout, truth, settle_s=ev.settle_s, position=ev.position)
    for est in estimates:
        tracker.add(est)
    for sensor, rows in sched.nis.items():
        for t, nis, dim in rows:
            tracker.add_nis(sensor, nis, dim, t=t)
    track = tracker.summary()
    # malformed lines of configured sensors are counted by the scheduler, the others by the parser
    sensors = {name: dict(s.counters) for name, s in system.sensors.items()}
    for name, n in parsed.malformed.items():
        if name not in system.sensors:
            sensors.setdefault(name or "?", dict(received=0, used=0, rejected=0, malformed=0, late=0))["malformed"] += n
    t_all = [e.t for e in estimates]
    duration = (max(t_all) - min(t_all)) if t_all else 0.0
    steps = dict(sched.steps)
    summary: dict[str, Any] = {
        "config": str(system.path) if system.path else system.spec.name,
        "filter": system.filter.name,
        "input": str(source),
        "duration_s": duration,
        "wall_s": result["wall_s"],
        "steps": steps,
        "us_per_predict": 1e6 * sched.time_s["predict"] / steps["predict"] if steps["predict"] else None,
        "us_per_update": 1e6 * sched.time_s["update"] / steps["update"] if steps["update"] else None,
        "sensors": sensors,
    }
    if track.get("errors"):
        summary["errors"] = track["errors"]
        if ev.position:
            summary["errors"]["position_elements"] = list(ev.position)
    if track.get("consistency"):
        summary["consistency"] = track["consistency"]
    if sched.unused:
        summary["ignored_sensors"] = dict(sched.unused)
    if result["events"]:
        summary["events"] = dict(result["events"])
    counters = getattr(system.filter, "counters", None)
    if counters:
        summary["filter_counters"] = dict(counters)
    return summary


class EventNotes:
    """Prints events a user should see while a replay runs (warnings, gaps, malformed lines, late
    messages, rejections), the first few of each kind with sensor, time and line, then a count."""

    SHOWN = {"warning": 10, "cleared": 10, "gap": 5, "malformed": 3, "late": 3, "rejected": 3, "no_fix": 3}

    def __init__(self, stream, enabled: bool = True):
        self.stream = stream
        self.enabled = enabled
        self.counts: dict[str, int] = {}

    def __call__(self, event: Event) -> None:
        n = self.counts.get(event.kind, 0) + 1
        self.counts[event.kind] = n
        limit = self.SHOWN.get(event.kind, 0)
        if self.enabled and n <= limit:
            at = f"t={event.t:.3f} s " if math.isfinite(event.t) else ""
            who = f"{event.sensor}: " if event.sensor else ""
            more = f" (further {event.kind} events are counted in the summary)" if n == limit else ""
            print(f"{event.kind}: {at}{who}{event.detail}{more}", file=self.stream)

    def close(self) -> None:
        self.stream.flush()


def run(args: argparse.Namespace) -> int:
    from fusion import report
    from fusion.sinks.estimates import EstimateWriter
    from fusion.sinks.summary import write_summary_json

    override = filter_override(args.config, args.filter, args.filter_param)
    system = load_system(args.config, filter_override=override)
    source = args.input or system.recording
    if source is None:
        raise ConfigError(f"{args.config}: no 'recording:' in the config; give one with --input LOG")
    writer = EstimateWriter(args.output, system.layout) if args.output else None
    show_progress = not args.no_progress and not args.quiet and sys.stdout.isatty()
    with report.progress(_duration_hint(source), enabled=show_progress) as tick:
        try:
            notes = EventNotes(sys.stderr, enabled=not args.quiet)
            result = replay(system, source, on_estimate=writer.on_estimate if writer else None,
                            on_event=notes, progress=tick)
            notes.close()
        finally:
            if writer:
                writer.close()
    summary = summarize(system, source, result)
    if args.summary_json:
        write_summary_json(args.summary_json, summary)
    if not args.quiet:
        report.print_summary(summary)
    if args.plot:
        _plot(args.plot, system, result)
    return 0


def _duration_hint(source: str | Path) -> float | None:
    """Last time stamp of a recording, read from its tail (for the progress bar), or None."""
    if str(source) == "-":
        return None
    try:
        with open(source, "rb") as fh:
            fh.seek(0, 2)
            size = fh.tell()
            fh.seek(max(0, size - 4096))
            tail = fh.read().decode("utf-8", "replace").splitlines()
        for line in reversed(tail):
            head = line.split(",", 1)[0]
            try:
                return float(head)
            except ValueError:
                continue
    except OSError:
        return None
    return None


def _plot(path: str, system: System, result: dict[str, Any]) -> None:
    from fusion.metrics import Truth
    from fusion.sinks.plot import plot_run

    est = result["estimates"]
    sched: Scheduler = result["scheduler"]
    names = result["parsed"].header.fields.get("truth")
    truth = Truth.from_messages(sched.truth, names) if sched.truth and names else None
    t = np.array([e.t for e in est])
    x = np.array([e.belief.x for e in est]) if est else np.zeros((0, system.layout.n))
    sd = np.array([e.belief.sd for e in est]) if est else np.zeros((0, system.layout.n))
    nis = {s: (np.array([r[0] for r in rows]), np.array([r[1] for r in rows]), rows[0][2])
           for s, rows in sched.nis.items() if rows}
    plot_run(path, system.layout, t, x, sd, truth, system.beacons, nis, title=f"{system.spec.name} ({system.filter.name})")
