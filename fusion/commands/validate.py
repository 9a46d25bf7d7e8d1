"""``fusion validate FILE...``: schema, plugin names, parameters and dimensions, without running."""
from __future__ import annotations

import argparse
import stat
import sys
import traceback
from pathlib import Path

from fusion.errors import ConfigError, FusionError, InputError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("validate", help="check configs without running them",
                       description="Check each system YAML: schema, plugin names and parameters, dimensions "
                                   "(R is m x m for its model, the initial belief fits the state, beacons exist, "
                                   "a measurement model's h and jacobian at the initial mean have its dim values, "
                                   "the process model's f, jacobian and Q there have the state's shape, are finite, "
                                   "and Q is symmetric positive semi-definite) "
                                   "and that its recording exists. Exit code 2 if any is invalid.")
    p.add_argument("files", nargs="+", metavar="FILE", help="system YAML files")
    p.add_argument("--input", "-i", metavar="LOG", default=None,
                   help="check the configs against this recording instead of their own: its header's field, "
                        "beacons, receivers, gravity and origin must not contradict the config's (exit 2)")
    p.set_defaults(func=run)


_KINDS = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device (a terminal or serial port)"),
          (stat.S_ISSOCK, "a socket"), (stat.S_ISBLK, "a block device"))


def _stream_kind(rec: Path, where: str) -> str | None:
    """What ``rec`` is when it is a stream validate must not read (reading would wait for a writer or a
    device, and take what the run should read): a FIFO, a terminal or serial port, a socket, a block device;
    None for a regular file. A path the system cannot look up (a symlink loop, a component that is a file,
    permission) is a ConfigError naming it and why."""
    try:
        mode = rec.stat().st_mode
    except FileNotFoundError:
        raise ConfigError(f"{where}: {rec} does not exist") from None
    except OSError as exc:
        raise ConfigError(f"{where}: {rec}: {exc.strerror or exc}") from None
    return next((kind for test, kind in _KINDS if test(mode)), None)


def _check_recording(path: str, system, rec: Path) -> str | None:
    """The recording is a readable log (not binary) and every beacon its header declares (``# beacon B5: x
    y z``, as ``fusion simulate`` writes) is in the config's ``beacons:``, when the config has beacons: a
    range to a beacon the config lacks would be malformed at every cycle. A stream (FIFO, device) is not
    read: returns a note saying so (None otherwise)."""
    from fusion.logformat import read_header
    from fusion.sources.recording import open_lines
    from fusion.yamlsource import load_yaml

    where = load_yaml(path).where(["recording"])
    kind = _stream_kind(rec, where)
    if kind is not None:
        return f"recording {rec} is {kind}: not read (its header is checked when a run reads it)"
    try:
        lines = open_lines(rec)
        try:
            header = read_header(lines)
        finally:
            lines.close()  # type: ignore[attr-defined]
    except InputError as exc:   # a directory, empty, binary: no log to replay
        raise ConfigError(f"{where}: {exc}") from None
    except OSError as exc:      # unreadable: permission, an I/O error (/proc/self/mem)
        raise ConfigError(f"{where}: cannot read {rec}: {exc.strerror or exc}") from None
    missing = [b for b in header.beacons if b not in system.beacons]
    if system.beacons and missing:
        where = load_yaml(path).where(["beacons"])
        shown = ", ".join(f"{b}: {list(header.beacons[b])}" for b in missing)
        raise ConfigError(f"{where}: the recording {rec.name} declares beacon(s) the config does not define "
                          f"({shown}); their ranges would all be malformed. Defined: {sorted(system.beacons)}")
    return None


#: The step (s) the process model is probed over.
PROBE_DT = 0.1


def _writes_its_argument(exc: Exception) -> bool:
    """The exception of a model that wrote into the read-only state it was given."""
    return isinstance(exc, ValueError) and "read-only" in str(exc)


def _check_models(path: str, system) -> None:
    """Each measurement model's ``h`` at the initial mean returns ``(dim,)``, and ``(2, dim)`` for two states
    (fusion.testing.check_measurement_vectorised checks the same on random states), finite, and its
    ``jacobian`` (when the filter uses it) ``(dim, n)``: a wrong one would fail every update of the sensor in
    the run. A model whose ``h`` needs a message first (the range to the beacon a message names) raises here
    and is not checked. The process model: :func:`_check_process`."""
    import numpy as np

    from fusion.errors import ConfigError, ModelFault
    from fusion.yamlsource import load_yaml
    from fusion_plugins.filters.checks import array_of, finite, frozen, unchecked

    x0 = frozen(np.asarray(system.x0, dtype=float))   # read-only: a model that writes into it raises
    n = x0.shape[0]
    _check_process(path, system, x0)
    uses_h_jacobian = not _sigma_point(system.filter)
    for name, sensor in system.sensors.items():
        model = unchecked(sensor.model)   # probed as written, not through the run's checking adapter
        if model is None or not hasattr(model, "h"):
            continue
        where = load_yaml(path).where(["sensors", name, "model"])
        try:
            dim = int(model.dim)
            h1, h2 = model.h(x0), model.h(np.stack([x0, x0]))
            H = model.jacobian(x0) if uses_h_jacobian else None
        except Exception as exc:   # unbound until observe(), or needs what the run builds: the run reports it
            if _writes_its_argument(exc):
                raise ConfigError(f"{where}: measurement model {model.name!r} writes into the state it is given "
                                  f"({type(exc).__name__}: {exc}); every update of {name} would fail") from None
            continue
        one, two = np.shape(h1), np.shape(h2)
        if one != (dim,) or two != (2, dim):
            raise ConfigError(f"{where}: measurement model {model.name!r} (dim {dim}): h at the initial mean "
                              f"returned shape {one}, expected ({dim},)" + ("" if two == (2, dim) else
                              f"; on 2 states {two}, expected (2, {dim})") + "; every update of "
                              f"{name} would fail")
        try:
            finite(array_of(h1, (dim,), "h", "the initial mean"), "h", "the initial mean", x0)
            if H is not None:
                H = array_of(np.atleast_2d(H), (dim, n), "jacobian", "the initial mean")
                finite(H, "jacobian", "the initial mean", x0)
        except ModelFault as exc:
            raise ConfigError(f"{where}: measurement model {model.name!r} (dim {dim}): {exc}; every update of "
                              f"{name} would fail") from None


def _sigma_point(flt) -> bool:
    """Whether the filter is a sigma-point one (ukf, srukf), which never calls a measurement ``jacobian``."""
    from fusion_plugins.filters.sigma_point_filter import SigmaPointFilter

    return isinstance(flt, SigmaPointFilter)


def _check_process(path: str, system, x0) -> None:
    """The process model at the initial mean ``x0`` (read-only), with a zero input and a step of
    :data:`PROBE_DT`: ``f`` returns ``(n,)`` (``(2, n)`` for two states), ``jacobian`` ``(n, n)`` or None (when
    the filter uses it), ``Q`` ``(n, n)``, all finite, Q symmetric positive semi-definite (the filters' own
    checks, plugins/filters/checks.py): a wrong one would fail every prediction. A model that raises there
    (it may need a real input) is not checked, unless it wrote into the state it was given."""
    import numpy as np

    from fusion.errors import ConfigError, ModelFault
    from fusion.yamlsource import load_yaml
    from fusion_plugins.filters.checks import QCheck, array_of, finite, unchecked

    process, n = unchecked(system.process), x0.shape[0]   # probed as written, not through the checking adapter
    u = np.zeros(process.input_dim) if process.input_dim else None
    flt = system.filter
    uses_jacobian = not _sigma_point(flt) or flt.use_linear_prediction(process)
    where = load_yaml(path).where(["process"])
    at = f"the initial mean (dt = {PROBE_DT} s{', zero input' if u is not None else ''})"
    try:
        f1, f2 = process.f(x0, u, PROBE_DT), process.f(np.stack([x0, x0]), u, PROBE_DT)
        F = process.jacobian(x0, u, PROBE_DT) if uses_jacobian else None
        Q = process.Q(x0, u, PROBE_DT)
    except Exception as exc:
        if _writes_its_argument(exc):
            raise ConfigError(f"{where}: process model {process.name!r} writes into the state it is given "
                              f"({type(exc).__name__}: {exc}); every prediction would fail") from None
        return
    try:
        finite(array_of(f1, (n,), "f", at), "f", at, x0)
        array_of(f2, (2, n), "f", "2 states")
        if F is not None:
            finite(array_of(F, (n, n), "jacobian", at), "jacobian", at, x0)
        QCheck()(Q, n, "Q", at, x0)
    except ModelFault as exc:
        raise ConfigError(f"{where}: process model {process.name!r} ({n} states): {exc}; every prediction "
                          "would fail") from None


def run(args: argparse.Namespace) -> int:
    from fusion.config import load_system

    bad = 0
    from fusion.config import OWN_RECORDING
    from fusion.header_checks import check as check_header

    given = getattr(args, "input", None)
    for path in args.files:
        try:
            system = load_system(path, recording=OWN_RECORDING if given is None else given)
            rec = system.recording if given is None else Path(given)
            note = _check_recording(path, system, rec) if rec is not None else None
            check_header(system, system.world, str(path))
            _check_models(path, system)
        except FusionError as exc:
            bad += 1
            if getattr(args, "debug", False):
                traceback.print_exc()
            print(f"{exc}", file=sys.stderr)
            continue
        sensors = ", ".join(f"{n} ({s.role})" for n, s in system.sensors.items())
        if note:
            print(f"{path}: note: {note}", file=sys.stderr)
        print(f"{path}: ok: {system.spec.name}: {system.process.name} {system.layout.n} states, "
              f"filter {system.filter.name}, sensors {sensors}")
    return 2 if bad else 0
