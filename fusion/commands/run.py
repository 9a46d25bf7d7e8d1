"""``fusion run CONFIG``: replay a recording through the configured estimator and report."""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fusion.errors import ConfigError, FusionError

if TYPE_CHECKING:
    from fusion.api import Event


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="replay a recording through a config and print a summary",
                       description="Replay a recording (the config's own, or --input) through the estimator the "
                                   "config composes; print a summary with errors against truth when the recording "
                                   "has truth lines.")
    p.add_argument("config", help="system YAML (e.g. configs/abps_ins.yaml)")
    p.add_argument("--input", "-i", metavar="SOURCE", action=Once,
                   help="recording to replay instead of the config's own ('-' for stdin), or any registered source: "
                        "a serial port (/dev/ttyUSB0, socket://host:port, loop://) or a plugin's scheme")
    p.add_argument("--filter", metavar="NAME", action=Once, help="use this filter instead of the config's (kf, ekf, iekf, ukf, srukf)")
    p.add_argument("--filter-param", metavar="KEY=VALUE", action="append", default=[],
                   help="set a filter parameter (repeatable; VALUE is YAML, e.g. alpha=0.5)")
    p.add_argument("--output", "-o", metavar="PATH", action=Once,
                   help="write estimates: the sink is chosen by suffix (.csv, .jsonl, or a plugin's; '-' CSV on stdout)")
    p.add_argument("--summary-json", metavar="PATH", action=Once, help="write the summary as JSON")
    p.add_argument("--plot", metavar="PATH.png", action=Once, help="plot trajectory, errors with 3-sigma bounds and NIS")
    p.add_argument("--smooth", action="store_true",
                   help="Rauch-Tung-Striebel smoothing after the forward filter: --output and the summary give the "
                        "smoothed estimates, the summary the filtered and smoothed errors side by side")
    p.add_argument("--smooth-lag", metavar="SECONDS", type=float, default=None,
                   help="fixed-lag smoother: each estimate SECONDS late, smoothed over that window")
    p.add_argument("--force", action="store_true", help="replace output files that exist")
    p.add_argument("--quiet", "-q", action="store_true",
                   help="no table on stdout (on stderr when an output is '-', so stdout holds only that output) and no "
                        "progress bar; warnings still go to stderr")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--allow-degraded", action="store_true",
                   help="exit 0 even when the run's health says its estimate cannot be trusted (exit 4 otherwise; "
                        "the config's health.allow_degraded does the same)")
    p.set_defaults(func=run)


class Once(argparse.Action):
    """An option that takes one value and may be given once: a second ``-o b.csv`` (``--plot``, ``--filter``,
    ``--input``) is refused (exit 2) where argparse would keep the last and drop the first request without a
    word. One run writes one output of each kind; run it again for another."""

    def __call__(self, parser, namespace, values, option_string=None):
        before = getattr(namespace, self.dest, None)
        if before is not None and getattr(namespace, f"_{self.dest}_given", False):
            raise argparse.ArgumentError(self, f"given twice ({before} and {values}): a run takes one; give it "
                                               "once (run again for another)")
        setattr(namespace, f"_{self.dest}_given", True)
        setattr(namespace, self.dest, values)


def filter_override(config: str | Path, name: str | None, params: list[str]) -> Any:
    """The filter spec after --filter/--filter-param (fusion.overrides, imported when used)."""
    from fusion.overrides import filter_override as _override

    return _override(config, name, params)


class EventNotes:
    """Prints events a user should see while a replay runs (warnings, gaps, malformed lines, late
    messages, rejections), the first few of each kind with sensor, time and line, then a count."""

    SHOWN = {"warning": 10, "cleared": 10, "gap": 5, "malformed": 3, "late": 3, "rejected": 3, "no_fix": 3,
             "time": 3, "clock": 3, "not_positive_definite": 3}

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
    from fusion.outputs import stdout_carries_data

    # an output on stdout ('-'): a plugin's print() goes to stderr for the whole command, never into the data
    with stdout_carries_data("-" in (args.output, args.summary_json, args.plot)):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from fusion import pipeline, report
    from fusion.config import load_system
    from fusion.sinks.summary import write_summary_json
    from fusion.sources.select import open_sink, open_source

    refuse_empty(args, "--input", "--output", "--summary-json", "--plot")
    override = filter_override(args.config, args.filter, args.filter_param)
    from fusion.config import OWN_RECORDING
    from fusion.header_checks import check as check_header

    system = load_system(args.config, filter_override=override,
                         recording=OWN_RECORDING if args.input is None else args.input)
    source = system.recording if args.input is None else args.input
    if source is None:
        raise ConfigError(f"{args.config}: no 'recording:' in the config; give one with --input LOG")
    check_header(system, system.world, str(args.config))   # a config that contradicts its recording: exit 2
    from fusion.outputs import check_outputs

    src = open_source(str(source), system.registry)
    # the files the source reads, by their paths (a file:// URL, a plugin's scheme): never an output
    check_outputs({"--output": args.output, "--summary-json": args.summary_json, "--plot": args.plot},
                  [args.config, source, *src.input_paths()], force=args.force)
    if args.plot:
        from fusion.sinks.plot import plot_format

        plot_format(args.plot)
    from fusion.api import Opens, has

    if has(src, Opens):   # a missing recording or an unopenable port: one line, before any output is made
        src.open()
    guarded = [guard_sink(open_sink(args.output, system.layout, system.registry))] if args.output else []
    from fusion.health import HealthWatch, spec_of

    watch = HealthWatch(system, spec_of(system))   # the filtered estimates' updates, for the health rule
    plot = None
    if args.plot:
        from fusion.sinks.plot_recorder import PlotRecorder

        plot = PlotRecorder()
    from fusion.outputs import data_stdout

    show_progress = not args.no_progress and not args.quiet and data_stdout().isatty()
    with report.progress(_duration_hint(source), enabled=show_progress) as tick:
        notes = EventNotes(sys.stderr)   # -q hides the table and progress only, never a warning
        smoothing = _smoothing(args, system)
        if smoothing is None:
            result = pipeline.run(system, src, [*guarded, watch], on_event=notes, progress=tick, plot=plot,
                                  label=str(source))
        else:
            from fusion.smoothing import run_smoothed

            result = run_smoothed(system, src, guarded, on_event=notes, progress=tick, plot=plot, label=str(source),
                                  forward_sinks=[watch], **smoothing)
        notes.close()
    summary = result.summary
    verdict = _assess(system, result, watch, source)
    if args.summary_json:
        write_summary_json(args.summary_json, summary)
    if not args.quiet:
        # with an output on stdout ('-'), the table goes to stderr: stdout holds only that output
        console = summary_console(stderr="-" in (args.output, args.summary_json, args.plot))
        report.print_summary({k: v for k, v in summary.items() if k != "smoothed"}, console=console)
        if "smoothed" in summary:
            from fusion.smoothing.report import print_smoothed

            print_smoothed(summary, console=console)
    if plot is not None:
        plot.write(args.plot, system, result.stats, title=f"{system.spec.name} ({system.filter.name})")
    for sink in guarded:
        if sink.error is not None:  # the output failed (disk full): after the summary, one line, exit 2
            raise sink.error
    report_plugin_errors("run", result, debug=getattr(args, "debug", False))
    if result.interrupted:
        print("fusion run: interrupted; the summary covers what was read", file=sys.stderr)
        return 130
    if result.source_error is not None:
        print(f"fusion run: error: the input stopped early: {result.source_error}; the summary covers what was "
              "read", file=sys.stderr)
        return 2
    if result.component_error is not None:
        print(f"fusion run: error: the run stopped: {result.component_error}; the summary covers what was "
              "processed", file=sys.stderr)
        return 2
    if not result.stats.estimates:   # a log this config cannot use (or nothing in it): a user error
        print(f"fusion run: error: {summary['not_started']}; the summary covers what was read", file=sys.stderr)
        return 2
    if result.plugin_errors:   # an observer failed: the run's outputs are complete, the plugin is not
        return 2
    if not result.stats.last_finite:
        print("fusion run: the estimate ended non-finite (the filter diverged); see the summary's health",
              file=sys.stderr)
        return 3
    return _degraded_exit(verdict, args, system)


def _assess(system: Any, result: Any, watch: Any, source: Any) -> Any:
    """The health Verdict of a run that made estimates (None otherwise), written into its summary's
    ``health`` (fusion.health); ``source`` the recording (its header lines name the likely causes)."""
    from fusion.health import assess

    if not result.stats.estimates:
        return None
    return assess(system, result.summary, watch, result.parsed.header, source)


def _degraded_exit(verdict: Any, args: argparse.Namespace, system: Any) -> int:
    """0, or DEGRADED_EXIT (4) after the findings on stderr, the main one on the last line, when the
    estimate cannot be trusted and neither --allow-degraded nor health.allow_degraded says to go on."""
    from fusion.health import DEGRADED_EXIT, spec_of

    if verdict is None or not verdict.degraded:
        return 0
    allowed = args.allow_degraded or spec_of(system).allow_degraded
    for finding in verdict.findings[1:]:
        print(f"fusion run: also: {finding.line()}", file=sys.stderr)
    if allowed:
        print(f"fusion run: degraded, exit 0 as allowed (--allow-degraded or health.allow_degraded): "
              f"{verdict.findings[0].line()}", file=sys.stderr)
        return 0
    print(f"fusion run: degraded: the estimate cannot be trusted (exit {DEGRADED_EXIT}; --allow-degraded or "
          f"health.allow_degraded for 0): {verdict.findings[0].line()}", file=sys.stderr)
    return DEGRADED_EXIT


def report_plugin_errors(command: str, result: Any, debug: bool = False) -> None:
    """One line on stderr per plugin observer that raised during the run (``RunResult.plugin_errors``: a hook,
    a plugin's sink), naming the plugin, after the outputs are written (they are complete: the run went on
    without it); with ``--debug`` each failure's traceback too. The command then exits 2."""
    errors = getattr(result, "plugin_errors", ())
    if not errors:
        return
    if debug:
        import traceback

        for exc in getattr(result, "plugin_exceptions", ()):
            traceback.print_exception(exc, file=sys.stderr)
    for text in errors:
        print(f"fusion {command}: error: {text}", file=sys.stderr)
    print(f"fusion {command}: the run went on without it: the summary and the other outputs are complete (exit 2)",
          file=sys.stderr)


def summary_console(stderr: bool = False):
    """The rich Console of the summary table: on stdout (stderr when an output is ``-``). A closed stdout
    (``fusion run | head -2``) raises BrokenPipeError, which the CLI ends quietly (exit 141), where rich's
    own Console would exit 1."""
    from rich.console import Console

    class _Console(Console):
        def on_broken_pipe(self) -> None:
            self.quiet = True
            raise BrokenPipeError

    return _Console(stderr=stderr)


def refuse_empty(args: argparse.Namespace, *options: str) -> None:
    """ConfigError for an option given as the empty text (``--input "$LOG"`` with LOG unset): never read
    as "not given", which would silently replay the config's own recording or drop an output."""
    for option in options:
        if getattr(args, option.lstrip("-").replace("-", "_"), None) == "":
            raise ConfigError(f"{option} '': empty (an unset shell variable?); give a path, or leave {option} out")


class _KeepSinkError:
    """A sink of the run whose FusionError (a write that failed: disk full, ``/dev/full``) is kept instead of
    ending the run: the sink is closed (the estimates sink has already removed its cut temporary file) and
    gets nothing more, the run goes on, its summary is written and printed, and ``run`` raises the kept
    error last (one line naming the path, exit 2). A closed standard output (fusion.outputs.StdoutClosed)
    still ends the run at once."""

    def __init__(self, sink: Any):
        self.sink = sink
        self.error: FusionError | None = None

    def _keep(self, exc: FusionError) -> None:
        from fusion.outputs import StdoutClosed

        if isinstance(exc, StdoutClosed):
            raise exc
        self.error = exc
        try:
            self.sink.close()
        except FusionError:
            pass

    def _forward(self, method: str, item) -> None:
        if self.error is None:
            try:
                getattr(self.sink, method)(item)
            except FusionError as exc:
                self._keep(exc)

    def on_estimate(self, estimate) -> None:
        self._forward("on_estimate", estimate)

    def close(self) -> None:
        if self.error is None:
            try:
                self.sink.close()
            except FusionError as exc:
                from fusion.outputs import StdoutClosed

                if isinstance(exc, StdoutClosed):
                    raise
                self.error = exc

    def discard(self) -> None:
        """Drop what the sink wrote, when it can (an incomplete smoothed output: fusion.smoothing.run)."""
        if self.error is None:
            getattr(self.sink, "discard", self.sink.close)()


class _KeepSinkErrorEvents(_KeepSinkError):
    """``_KeepSinkError`` of a sink that takes events too (fusion.api.ReceivesEvents)."""

    def on_event(self, event) -> None:
        self._forward("on_event", event)


def guard_sink(sink: Any) -> _KeepSinkError:
    """``sink`` wrapped so that its write errors are reported after the summary (``_KeepSinkError``)."""
    from fusion.api import ReceivesEvents, has

    return _KeepSinkErrorEvents(sink) if has(sink, ReceivesEvents) else _KeepSinkError(sink)


def _smoothing(args: argparse.Namespace, system) -> dict[str, Any] | None:
    """run_smoothed's options from --smooth / --smooth-lag and the config's ``smoother:`` (None: no
    smoothing). The command line wins over the config."""
    spec = getattr(system.spec, "smoother", None)
    lag = args.smooth_lag
    if lag is not None and args.smooth:
        raise ConfigError(f"--smooth and --smooth-lag {lag:g} exclude each other: --smooth is the full smoother "
                          "(every estimate uses the whole recording), --smooth-lag S the fixed-lag one; give one")
    if lag is not None:
        if not (lag >= 0.0 and math.isfinite(lag)):
            raise ConfigError(f"--smooth-lag {lag:g}: expected a finite number of seconds >= 0")
        return {"lag": lag, "disk": None if spec is None else spec.disk}
    if args.smooth:
        return {"lag": None, "disk": None if spec is None else spec.disk}
    if spec is not None and spec.enabled:
        return {"lag": spec.lag_s, "disk": spec.disk}
    return None


def _duration_hint(source: str | Path) -> float | None:
    """Last time stamp of a recording, read from its tail (for the progress bar), or None."""
    if str(source) == "-":
        return None
    try:
        if not Path(source).is_file():   # a device (/dev/zero) or a pipe has no tail: read() would not end
            return None
        with open(source, "rb") as fh:
            fh.seek(0, 2)
            size = fh.tell()
            fh.seek(max(0, size - 4096))
            tail = fh.read(4096).decode("utf-8", "replace").splitlines()
        for line in reversed(tail):
            head = line.split(",", 1)[0]
            try:
                return float(head)
            except ValueError:
                continue
    except OSError:
        return None
    return None
