"""Choosing a source for ``--input`` and a sink for ``--output`` through the registry.

Commands never import a source or sink class: a third party's ``udp://`` source or ``.tsv`` sink,
registered through its entry point, is used exactly like the built-ins.

Sources (``open_source``), in this order:

1. ``-``: standard input (the ``recording`` source);
2. ``SCHEME://...``: the source whose ``schemes`` has SCHEME (``file://``, pyserial's ``loop://``,
   ``socket://``, ``rfc2217://``, ...); an unknown scheme is an error listing the known ones;
3. a serial device (``COM3``, or an existing character device such as ``/dev/ttyUSB0`` or ``/dev/pts/3``):
   a source with ``devices = True``;
4. a file suffix claimed by a source's ``suffixes`` (a third party's may claim one of its own);
5. anything else: a recording in the log format (the ``recording`` source checks its contents).

Sinks (``open_sink``): ``-`` is CSV on stdout, and so is a FIFO or device without a suffix; otherwise the sink whose ``suffixes`` has the path's suffix;
an unknown or missing suffix is an error listing the known ones.
"""
from __future__ import annotations

import os
import re
import stat
from pathlib import Path
from typing import Any

from fusion.api import ConfigError, FusionError, Sink, Source, StateLayout

__all__ = ["open_source", "source_class", "open_sink", "sink_class"]

_SCHEME = re.compile(r"^([A-Za-z][A-Za-z0-9+.\-]*)://")
_COM = re.compile(r"^COM\d+$", re.IGNORECASE)
_NOT_PORTS = {"/dev/null", "/dev/zero", "/dev/full", "/dev/random", "/dev/urandom", "/dev/stdin", "/dev/tty"}
# Logs that need converting first (fusion import), recognised by suffix for a helpful message.
_IMPORT = {".ulg": "a PX4 ULog", ".bin": "an ArduPilot DataFlash log", ".tlog": "a MAVLink telemetry log"}


def _registry(registry):
    if registry is None:
        from fusion.registry import default_registry

        registry = default_registry()
    return registry


def _is_device(spec: str) -> bool:
    if _COM.match(spec):
        return True
    if spec in _NOT_PORTS:
        return False
    try:
        return stat.S_ISCHR(os.stat(spec).st_mode)
    except (OSError, ValueError):
        return False


def source_class(spec: str, registry=None, device: bool = False) -> type[Source]:
    """The registered source class that reads ``spec`` (see the module for the rules); ``device``: a
    text without a scheme is a port (``fusion tui --port``), even when no such device exists yet."""
    reg = _registry(registry)
    classes = [e.cls for e in reg.entries("source")]
    option = "--port" if device else "--input"
    if spec == "-":
        return reg.get("source", "recording")
    m = _SCHEME.match(spec)
    if m:
        scheme = m.group(1).lower()
        for cls in classes:
            if scheme in cls.schemes:
                return cls
        known = sorted({f"{s}://" for cls in classes for s in cls.schemes})
        raise ConfigError(f"{option} {spec}: no source reads {scheme}:// (known schemes: {', '.join(known)}; "
                          "a plugin can add one)")
    if device or _is_device(spec):
        for cls in classes:
            if cls.devices:
                return cls
        if device:
            raise ConfigError(f"--port {spec}: no source reads serial devices (is the serial source blocked?)")
    suffix = Path(spec).suffix.lower()
    if suffix:
        claimed = [cls for cls in classes if suffix in cls.suffixes]
        if claimed:
            return claimed[0]
        if suffix in _IMPORT:
            raise ConfigError(f"--input {spec}: {_IMPORT[suffix]}, not a recording; convert it first: "
                              f"fusion import {spec} -o {Path(spec).with_suffix('.log').name}")
    return reg.get("source", "recording")


def open_source(spec: str, registry=None, device: bool = False, **options: Any) -> Source:
    """The source for ``--input spec`` (not opened yet); ``options`` go to its Params (e.g. ``baud``,
    ``record`` for a serial port). A ConfigError when no source reads it or its options are wrong."""
    from pydantic import ValidationError

    cls = source_class(str(spec), registry, device=device)
    try:
        return cls.from_url(str(spec), **options)
    except ValidationError as exc:
        err = exc.errors()[0]
        field = ".".join(str(p) for p in err.get("loc", ())) or "?"
        raise ConfigError(f"{'--port' if device else '--input'} {spec}: source {cls.name!r}: {field}: {err.get('msg', exc)}") from None


def sink_class(path: str, registry=None) -> type[Sink]:
    """The registered sink class that writes ``path`` (by suffix; ``-`` is the CSV estimates sink)."""
    from fusion.outputs import is_stream

    reg = _registry(registry)
    suffix = Path(str(path)).suffix.lower()
    if str(path) == "-" or (not suffix and is_stream(path)):  # stdout, a FIFO, a device: CSV
        return reg.get("sink", "estimates")
    classes = [e.cls for e in reg.entries("sink")]
    for cls in classes:
        if suffix and suffix in cls.suffixes:
            return cls
    known = sorted({s for cls in classes for s in cls.suffixes})
    what = f"suffix {suffix!r}" if suffix else "no suffix"
    raise ConfigError(f"--output {path}: {what}; known output suffixes: {', '.join(known)} ('-' for CSV on stdout)")


def open_sink(path: str, layout: StateLayout, registry=None) -> Sink:
    """The sink for ``--output path``, opened for estimates of ``layout``. A third-party sink that raises
    while it is built (anything but a FusionError, which says what itself) is a ConfigError naming it."""
    cls = sink_class(path, registry)
    try:
        return cls.for_path(str(path), layout)
    except FusionError:
        raise
    except Exception as exc:
        provider = _registry(registry).provider_of(cls)
        if provider.endswith("(built-in)") and not isinstance(exc, OSError):
            raise
        raise ConfigError(f"--output {path}: component {cls.name!r} (sink, from {provider}) failed to build: "
                          f"{type(exc).__name__}: {exc}") from exc
