"""The likely causes of a degraded run, named from the config and the recording (fusion.health.rule): the
config's constants against the recording's header, a latency, a gate too tight, a missing recovery. Each
is one short clause naming the config's field path and its value, so the user knows where to look."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

__all__ = ["SensorContext", "RunContext", "context_of"]


@dataclass(frozen=True)
class SensorContext:
    """One measurement sensor as configured, and what the recording's header says of it."""

    name: str
    model: str = ""                   # "type k=v ..." of sensors.NAME.model
    time_offset: float = 0.0          # s
    gate: str = ""                    # "chi2 probability=0.999", "" without a gate
    recovery: str = ""                # "after_s=5", "" without one
    header: tuple[str, ...] = ()      # the recording's "# NAME key: value" lines


@dataclass(frozen=True)
class RunContext:
    """The run's configuration as the causes name it."""

    max_latency: float = 0.0
    late_policy: str = "drop"
    sensors: dict[str, SensorContext] = field(default_factory=dict)
    header_beacons: int = 0           # beacons the recording's header declares
    config_beacons: int = 0
    header_receivers: int = 0         # "# receiver N: x y z" lines (a receiver array)
    header_read: bool = False         # the header's lines were read (a file; not stdin, a port, lines in memory)
    beacons_known: bool = False       # the header's beacons are known (read, or parsed by the run)

    def sensor(self, name: str | None) -> SensorContext:
        return self.sensors.get(name or "", SensorContext(name or ""))


def _component(spec: Any) -> str:
    """``type k=v ...`` of a component spec (a name or a mapping with ``type``)."""
    if spec is None:
        return ""
    if isinstance(spec, str):
        return spec
    if isinstance(spec, dict):
        rest = " ".join(f"{k}={_short(v)}" for k, v in spec.items() if k != "type")
        return f"{spec.get('type', '?')} {rest}".strip()
    return str(spec)


def _short(v: Any, most: int = 60) -> str:
    text = str(v).replace(" ", "")
    return text if len(text) <= most else text[: most - 3] + "..."


#: Header lines read for the causes: a header is at the top of a recording, and a few hundred lines long.
_HEADER_LINES = 5000


def header_lines(path: Any) -> list[str]:
    """The ``#`` lines at the top of a recording (without the ``#``): a file's, or those of a list of lines
    (a sweep's recording in memory); [] for anything else (stdin, a port, a plugin's source)."""
    import os
    import stat

    if isinstance(path, (list, tuple)):
        return [line[1:].strip() for line in _top(path)]
    try:
        if path is None or not stat.S_ISREG(os.stat(path).st_mode):
            return []
        out = []
        with open(path, encoding="utf-8", errors="replace") as fh:
            for _, line in zip(range(_HEADER_LINES), fh):
                if line.startswith("#"):
                    out.append(line[1:].strip())
                elif line.strip():
                    break
        return out
    except (OSError, ValueError):
        return []


def _top(lines: Any) -> list[str]:
    out = []
    for _, line in zip(range(_HEADER_LINES), lines):
        if line.startswith("#"):
            out.append(line)
        elif line.strip():
            break
    return out


def context_of(system: Any, header: Any = None, recording: Any = None) -> RunContext:
    """The RunContext of a wired ``system`` (fusion.config.System), a recording's parsed ``header``
    (fusion.logformat.Header, or None) and its file (``recording``: a path, for the ``# SENSOR key: value``
    lines the parsed header does not keep; None: not read)."""
    spec = system.spec
    lines = header_lines(recording)
    sensors = {}
    for name, s in spec.sensors.items():
        if s.role != "measurement" or not s.enabled:
            continue
        rec = s.recovery
        sensors[name] = SensorContext(
            name=name, model=_component(s.model), time_offset=float(s.time_offset), gate=_component(s.gate),
            recovery="" if rec is None else f"after_s={rec.after_s:g} action={rec.action}",
            header=tuple(line for line in lines if line.startswith(name + " ")))
    beacons = len(getattr(header, "beacons", {}) or {}) or sum(line.startswith("beacon ") for line in lines)
    return RunContext(max_latency=float(spec.scheduler.max_latency), late_policy=spec.scheduler.late_policy,
                      sensors=sensors, header_beacons=beacons, config_beacons=len(spec.beacons),
                      header_receivers=sum(line.startswith("receiver ") for line in lines),
                      header_read=bool(lines), beacons_known=bool(lines) or header is not None)


def constants(ctx: RunContext, sensor: str | None) -> str:
    s = ctx.sensor(sensor)
    mine = f"sensors.{sensor}.model {s.model}" if sensor and s.model else "the config's models"
    parts = [mine]
    if ctx.header_read:
        parts.append("the header: " + ("; ".join(s.header) if s.header else f"nothing of {sensor or 'it'}"))
    if ctx.beacons_known and (ctx.header_beacons or ctx.config_beacons):
        parts.append(f"beacons: {ctx.config_beacons} in the config, {ctx.header_beacons} in the header")
    if ctx.header_receivers:
        parts.append(f"a receiver array of {ctx.header_receivers} in the header (its numbering)")
    return f"the config's constants against the recording's header ({'; '.join(parts)})"


def latency(ctx: RunContext, sensor: str | None) -> str:
    s = ctx.sensor(sensor)
    where = f"sensors.{sensor}.time_offset {s.time_offset:g} s against " if sensor else ""
    return f"a latency ({where}scheduler.max_latency {ctx.max_latency:g} s, late_policy {ctx.late_policy})"


def gate(ctx: RunContext, sensor: str | None) -> str:
    s = ctx.sensor(sensor)
    if not sensor:
        return "a gate too tight (sensors.NAME.gate)"
    return f"a gate too tight (sensors.{sensor}.gate {s.gate or 'none'})"


def recovery(ctx: RunContext, sensor: str | None) -> str:
    s = ctx.sensor(sensor)
    if not sensor:
        return "a missing recovery (sensors.NAME.recovery)"
    if s.recovery:
        return f"a recovery that did not bring the sensor back (sensors.{sensor}.recovery {s.recovery})"
    return f"a missing recovery (sensors.{sensor}.recovery: none)"


def noise(ctx: RunContext, sensor: str | None) -> str:
    return f"a measurement noise too small (sensors.{sensor}.noise or the model's sd)" if sensor else \
        "a process or measurement noise too small"


def ordered(kind: str, ctx: RunContext, sensor: str | None, mostly_late: bool = False) -> list[str]:
    """The likely causes of a finding of ``kind``, likeliest first."""
    if kind == "shut_out" and mostly_late:
        return [latency(ctx, sensor), constants(ctx, sensor), gate(ctx, sensor), recovery(ctx, sensor)]
    if kind in ("shut_out", "locked_out"):
        return [constants(ctx, sensor), latency(ctx, sensor), gate(ctx, sensor), recovery(ctx, sensor)]
    if kind == "nis":
        return [constants(ctx, sensor), latency(ctx, sensor), noise(ctx, sensor)]
    return [constants(ctx, sensor), latency(ctx, sensor), gate(ctx, sensor), recovery(ctx, sensor)]
