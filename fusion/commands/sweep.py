"""``fusion sweep CONFIG --seeds N -o results.csv``: many seeded trials, one row each, and a summary."""
from __future__ import annotations

import argparse
import sys

from fusion.commands.run import Once
from fusion.errors import ConfigError

HELP = "run many seeded trials (simulate + run) over filters and parameters; one row a trial"
DESCRIPTION = """\
A trial simulates the scenario with one seed (fusion simulate) and runs the config, or a variant of it,
over that recording (fusion run). Every combination of --seeds x --filter x --param values is a trial;
each gives one row of the results file (position/velocity RMSE and max, NEES mean and in-95% fraction,
NIS mean per sensor, counts of updates, rejected, late, malformed, resets, wall time; with --smooth the
smoothed errors too). Trials already in the results file are skipped (resume); a trial that fails is a
row with its error and the sweep goes on (a rerun retries it). At the end: means with 95% confidence
intervals per variant, and paired Wilcoxon signed-rank comparisons between filters and between the
values of each parameter (same seeds).
"""
EPILOG = """\
examples:
  fusion sweep configs/uwb_pv_ukf.yaml --seeds 50 --filter ukf,ekf -o uwb.csv
  fusion sweep configs/uwb_pv_ukf.yaml --seeds 20 --param process.spectral_density=0.1,0.2,0.5 -o s.csv
  fusion sweep configs/uwb_pv_ukf.yaml --seeds 20 --param scenario.sensors.uwb.rate_hz=5,1 -o rate.parquet
  fusion sweep configs/uwb_pv_ukf.yaml --seeds 50 --smooth -o smooth.csv
  fusion sweep configs/abps_ins.yaml --seeds 200 --dask local --jobs 2 -o abps.csv
  fusion sweep configs/abps_ins.yaml --seeds 2000 --scheduler tcp://10.0.0.5:8786 -o abps.csv

engines (--engine): auto (default) = the batched filters in process for every variant they support
(kf, ekf, ukf, srukf; measurement sensors only), a process pool (--jobs) or Dask for the rest; batch,
serial, pool, dask force one. docs/sweep.md has the details and how to use a cluster.
"""


def register(sub) -> None:
    p = sub.add_parser("sweep", help=HELP, description=DESCRIPTION, epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config", metavar="CONFIG", help="system YAML (e.g. configs/uwb_pv_ukf.yaml)")
    p.add_argument("--scenario", metavar="S", help="scenario YAML to simulate (default: the one that made the "
                                                    "config's own recording)")
    p.add_argument("--seeds", metavar="N", required=True, help="N seeds 0..N-1, or A:B for seeds A..B-1")
    p.add_argument("--filter", metavar="NAMES", action=Once, help="comma-separated filters (default: the config's)")
    p.add_argument("--param", metavar="KEY=V1,V2", action="append", default=[],
                   help="a config (or scenario.*) value to vary; repeatable: the grid is every combination")
    p.add_argument("--smooth", action="store_true", help="also run the RTS smoother; smoothed columns in the rows")
    p.add_argument("--initial", default="config", choices=("config", "drawn"),
                   help="initial mean: the config's (default), or drawn per seed from N(true start, P0), the "
                        "Monte-Carlo protocol of a NEES test (needs truth in the recording)")
    p.add_argument("-o", "--output", metavar="RESULTS", required=True, action=Once, help="results file (.csv or .parquet)")
    p.add_argument("--engine", default="auto", choices=("auto", "batch", "serial", "pool", "dask"),
                   help="where trials run (default auto)")
    p.add_argument("--jobs", "-j", type=int, default=2, metavar="J", help="pool or LocalCluster workers (default 2)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--dask", metavar="local", choices=("local",), help="start a Dask LocalCluster of --jobs workers")
    g.add_argument("--scheduler", metavar="ADDRESS", help="use a running Dask scheduler (tcp://HOST:8786)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--quiet", "-q", action="store_true", help="no summary on stdout")
    p.set_defaults(func=run)


def seeds_of(text: str) -> range:
    """``N`` -> 0..N-1, ``A:B`` -> A..B-1; ConfigError otherwise."""
    try:
        if ":" in text:
            a, b = (int(v) for v in text.split(":", 1))
        else:
            a, b = 0, int(text)
    except ValueError:
        raise ConfigError(f"--seeds {text!r}: expected N (seeds 0..N-1) or A:B (seeds A..B-1)") from None
    if a < 0 or b <= a:
        raise ConfigError(f"--seeds {text!r}: needs at least one seed >= 0")
    if b - a > MAX_SEEDS:
        raise ConfigError(f"--seeds {text!r}: {b - a} seeds; at most {MAX_SEEDS} in one sweep (split it with A:B)")
    return range(a, b)


MAX_SEEDS = 1_000_000   # a sweep's trials are listed up front: 1e11 seeds would exhaust memory silently


class _Progress:
    """A rich progress bar on stderr (when it is a terminal)."""

    def __init__(self, enabled: bool):
        self.bar = None
        if enabled and sys.stderr.isatty():
            from rich.console import Console
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeRemainingColumn
            self.bar = Progress("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
                                TimeRemainingColumn(), console=Console(stderr=True), transient=True)
            self.task = None

    def __call__(self, done: int, total: int) -> None:
        if self.bar is None:
            return
        if self.task is None:
            self.bar.start()
            self.task = self.bar.add_task("trials", total=total)
        self.bar.update(self.task, completed=done)

    def close(self) -> None:
        if self.bar is not None and self.task is not None:
            self.bar.stop()


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from fusion.sweep.grid import default_scenario, parse_params, sweep, trials_of
    from fusion.sweep.report import print_report

    if not Path(args.config).exists():
        raise ConfigError(f"{args.config}: no such config file")
    if args.jobs < 1:
        raise ConfigError(f"--jobs {args.jobs}: needs at least 1")
    scenario = args.scenario or default_scenario(args.config)
    if not Path(scenario).exists():
        raise ConfigError(f"--scenario {scenario}: no such scenario file")
    filters = [f.strip() for f in args.filter.split(",")] if args.filter else [None]
    if args.filter and any(not f for f in filters):
        raise ConfigError(f"--filter {args.filter!r}: an empty name (e.g. --filter ukf,ekf)")
    twice = sorted({f for f in filters if filters.count(f) > 1})
    if args.filter and twice:   # each trial would run twice and be written once ("2 trials ... 4 run")
        raise ConfigError(f"--filter {args.filter!r}: {', '.join(twice)} given twice; name each filter once")
    params = parse_params(args.param)
    trials = trials_of(args.config, scenario, seeds_of(args.seeds), filters, params, args.smooth, args.initial)
    where = args.scheduler or args.dask
    bar = _Progress(not args.no_progress and not args.quiet)
    try:
        rows, info = sweep(trials, args.output, engine=args.engine, jobs=args.jobs, dask=where, progress=bar)
    finally:
        bar.close()
    if not args.quiet:
        print_report(rows, info, params, filters, args.smooth, sys.stdout)
    print(f"{args.output}: {len(rows)} trial(s) ({info['skipped']} already there, "
          f"{sum(info['engines'].values())} run: " + ", ".join(f"{k} {v}" for k, v in info["engines"].items()) + ")",
          file=sys.stderr)
    return 0
