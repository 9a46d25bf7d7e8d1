"""``fusion simulate SCENARIO -o LOG``: write a recording with truth from a scenario file."""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from fusion.errors import InputError

HELP = "simulate a scenario into a recording (log format with truth lines)"
DESCRIPTION = """\
Simulate the sensors of a scenario file (trajectory, beacons, sensors with rates, noise, biases and
faults) and write a recording in the fusion log format: a header with the scenario name, seed, beacon
positions and a '# fields' line per sensor, then time-sorted messages and 'truth' lines (true position,
velocity, attitude and sensor biases) at the highest sensor rate. The same scenario and seed always give
the same bytes.
"""
EPILOG = """\
examples:
  fusion simulate scenarios/example_2d.yaml -o recordings/example_2d.log
  fusion simulate scenarios/abps_mine.yaml -o /tmp/run7.log --seed 7
  fusion simulate scenarios/uwb_route1.yaml -o - --noise off | head

simulators available to a scenario's sensors (type: NAME): see `fusion plugins`; docs/simulate.md
describes the scenario format.
"""


def register(subparsers) -> None:
    p = subparsers.add_parser("simulate", help=HELP, description=DESCRIPTION, epilog=EPILOG,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenario", metavar="SCENARIO", help="scenario YAML file (e.g. scenarios/example_2d.yaml)")
    p.add_argument("-o", "--output", metavar="LOG", required=True, help="recording to write ('-' for stdout)")
    p.add_argument("--seed", type=int, default=None, metavar="N",
                   help="seed of the sensor noise (default: the scenario's `seed`)")
    p.add_argument("--noise", choices=("on", "off"), default="on",
                   help="'off': every measurement exact (no noise, biases, scale errors or outliers; "
                        "dropouts and gaps stay)")
    p.add_argument("--force", action="store_true", help="replace LOG if it exists")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fusion.simulate import simulate_file

    if args.seed is not None and args.seed < 0:
        from fusion.api import ConfigError
        raise ConfigError(f"--seed: must be >= 0, got {args.seed}")
    from fusion.outputs import check_outputs, write_text

    check_outputs({"-o": args.output}, [args.scenario], force=args.force)
    text = simulate_file(args.scenario, seed=args.seed, noise=args.noise == "on")
    if args.output == "-":
        sys.stdout.write(text)
        return 0
    out = Path(args.output)
    write_text(out, text, what="the recording")
    n = text.count("\n") - sum(1 for line in text.splitlines() if line.startswith("#"))
    print(f"wrote {out}: {n} lines, {len(text.encode('utf-8')) / 1e3:.0f} kB", file=sys.stderr)
    return 0
