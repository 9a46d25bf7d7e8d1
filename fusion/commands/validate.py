"""``fusion validate FILE...``: schema, plugin names, parameters and dimensions, without running."""
from __future__ import annotations

import argparse
import sys
import traceback

from fusion.errors import FusionError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("validate", help="check configs without running them",
                       description="Check each system YAML: schema, plugin names and parameters, dimensions "
                                   "(R is m x m for its model, the initial belief fits the state, beacons exist, "
                                   "a measurement model's h at the initial mean has its dim values) "
                                   "and that its recording exists. Exit code 2 if any is invalid.")
    p.add_argument("files", nargs="+", metavar="FILE", help="system YAML files")
    p.set_defaults(func=run)


def _check_recording(path: str, system, rec) -> None:
    from fusion.errors import ConfigError, InputError
    from fusion.logformat import read_header
    from fusion.sources.recording import open_lines
    from fusion.yamlsource import load_yaml

    """The recording is a log (not binary) and every beacon its header declares (``# beacon B5: x y z``, as
    ``fusion simulate`` writes) is in the config's ``beacons:``, when the config has beacons: a range to a
    beacon the config lacks would be malformed at every cycle."""
    lines = open_lines(rec)
    try:
        header = read_header(lines)
    except InputError as exc:   # a directory, empty, binary: no log to replay
        raise ConfigError(f"{load_yaml(path).where(['recording'])}: {exc}") from None
    finally:
        lines.close()  # type: ignore[attr-defined]
    missing = [b for b in header.beacons if b not in system.beacons]
    if system.beacons and missing:
        where = load_yaml(path).where(["beacons"])
        shown = ", ".join(f"{b}: {list(header.beacons[b])}" for b in missing)
        raise ConfigError(f"{where}: the recording {rec.name} declares beacon(s) the config does not define "
                          f"({shown}); their ranges would all be malformed. Defined: {sorted(system.beacons)}")


def _check_models(path: str, system) -> None:
    """Each measurement model's ``h`` at the initial mean returns ``(dim,)``, and ``(2, dim)`` for two states
    (fusion.testing.check_measurement_vectorised checks the same on random states): a wrong shape would fail
    every update of the sensor in the run. A model whose ``h`` needs a message first (the range to the beacon
    a message names) raises here and is not checked."""
    import numpy as np

    from fusion.errors import ConfigError
    from fusion.yamlsource import load_yaml

    x0 = np.asarray(system.x0, dtype=float)
    for name, sensor in system.sensors.items():
        model = sensor.model
        if model is None or not hasattr(model, "h"):
            continue
        try:
            dim = int(model.dim)
            one, two = np.shape(model.h(x0)), np.shape(model.h(np.stack([x0, x0])))
        except Exception:   # unbound until observe(), or needs what the run builds: the run reports it
            continue
        if one != (dim,) or two != (2, dim):
            where = load_yaml(path).where(["sensors", name, "model"])
            raise ConfigError(f"{where}: measurement model {model.name!r} (dim {dim}): h at the initial mean "
                              f"returned shape {one}, expected ({dim},)" + ("" if two == (2, dim) else
                              f"; on 2 states {two}, expected (2, {dim})") + "; every update of "
                              f"{name} would fail")


def run(args: argparse.Namespace) -> int:
    from fusion.config import load_system
    from fusion.yamlsource import load_yaml

    bad = 0
    for path in args.files:
        try:
            system = load_system(path)
            rec = system.recording
            if rec is not None and not rec.exists():
                raise FusionError(f"{load_yaml(path).where(['recording'])}: {rec} does not exist")
            if rec is not None:
                _check_recording(path, system, rec)
            _check_models(path, system)
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
