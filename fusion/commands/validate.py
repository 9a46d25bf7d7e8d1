"""``fusion validate FILE...``: schema, plugin names, parameters and dimensions, without running."""
from __future__ import annotations

import argparse
import sys
import traceback

from fusion.api import FusionError
from fusion.config import load_system


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("validate", help="check configs without running them",
                       description="Check each system YAML: schema, plugin names and parameters, dimensions "
                                   "(R is m x m for its model, the initial belief fits the state, beacons exist) "
                                   "and that its recording exists. Exit code 2 if any is invalid.")
    p.add_argument("files", nargs="+", metavar="FILE", help="system YAML files")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    bad = 0
    for path in args.files:
        try:
            system = load_system(path)
            rec = system.recording
            if rec is not None and not rec.exists():
                raise FusionError(f"{path}: recording: {rec} does not exist")
        except FusionError as exc:
            bad += 1
            if getattr(args, "debug", False):
                traceback.print_exc()
            print(f"{exc}", file=sys.stderr)
            continue
        sensors = ", ".join(f"{n} ({s.role})" for n, s in system.sensors.items())
        print(f"{path}: ok: {system.spec.name}: {system.process.name} {system.layout.n} states, "
              f"filter {system.filter.name}, sensors {sensors}")
    return 2 if bad else 0
