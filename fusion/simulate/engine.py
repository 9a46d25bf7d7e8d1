"""Run a scenario: build the trajectory and the sensor simulators, then write the log text.

The output follows DESIGN.md "Log format": a header (``# fusion-log 1``, ``# scenario:``, ``# seed:``,
metadata, ``# beacon NAME: x y z``, a ``# fields`` line per sensor and for ``truth``), then one message a
line sorted by time (ties: sensors in scenario order, truth last). Times have 6 decimals, values the
scenario's ``precision``. Every sensor draws from its own generator seeded by (seed, crc32(sensor name)),
so adding a sensor leaves the others' noise unchanged; the same scenario and seed give the same bytes.
"""
from __future__ import annotations

import datetime as _dt
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import ValidationError

from fusion.api import BuildContext, ConfigError
from fusion.logformat import format_line
from fusion.simulate.base import SensorSimulator, SimContext, sample_times
from fusion.simulate.scenario import Scenario
from fusion.simulate.trajectory import TrajectoryError, build_trajectory
from fusion.yamlsource import LocatedYAML, pydantic_errors

LOG_VERSION = "1"


def sensor_rng(seed: int, sensor: str) -> np.random.Generator:
    """The generator of one sensor: independent of the other sensors' names and order."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), zlib.crc32(sensor.encode("utf-8"))]))


def _document(sc: Scenario, where: str, text: str | None) -> LocatedYAML:
    """The scenario's YAML document, to locate an error (fusion.yamlsource, as a config's): from its text,
    else its sensors without lines."""
    if text:
        try:
            return LocatedYAML.from_text(text, where)
        except ConfigError:
            pass
    return LocatedYAML(where, {"sensors": dict(sc.sensors)}, None)


def build_simulators(sc: Scenario, registry=None, where: str = "<scenario>", text: str | None = None
                     ) -> dict[str, SensorSimulator]:
    """name -> simulator, each validated by its own Params (ConfigError naming the field path)."""
    if registry is None:
        from fusion.registry import default_registry
        registry = default_registry()
    beacons = {k: np.array(v + [0.0] * (3 - len(v)), float) for k, v in sc.beacons.items()}
    out: dict[str, SensorSimulator] = {}
    for name, spec in sc.sensors.items():
        cls = registry.get("simulator", spec["type"], where=f"{where}: sensors.{name}.type")
        try:
            params = cls.Params.model_validate(spec)
        except ValidationError as exc:
            raise pydantic_errors(_document(sc, where, text), exc, prefix=("sensors", name)) from None
        ctx = BuildContext(beacons=beacons, sensor=name, extra={"dim": sc.dim, "gravity": sc.gravity})
        out[name] = cls(params, ctx)
    return out


@dataclass
class SimStream:
    """The messages of one stream of a simulated recording before they become text: ``name`` (a sensor,
    or ``truth``), ``order`` (its rank among the streams: ties in time go by it), times ``t`` (N,) s,
    ``values`` (one tuple of floats or labels a message, or an array: ``table``) and the decimals of the
    values (``precision``)."""

    name: str
    order: int
    t: np.ndarray
    values: Any
    precision: int
    table: bool = False   # values an (N, m) array (the truth), formatted row by row from ``tolist()``


@dataclass
class SimParts:
    """A simulated recording as data: the ``#`` lines (without ``# ``: header, then one ``fields`` line
    per stream) and the streams; :func:`render` makes the text of :func:`simulate` from them."""

    header: list[str]
    streams: list[SimStream]


MAX_DURATION_S = 1e7      # s (~116 days) of one simulated recording
MAX_SAMPLES = 5e7         # messages of one stream (a few GB of text)
MAX_LINES = 1e7           # lines of one recording, all streams: held in memory (~300 B a line while formatted)


def simulate_parts(sc: Scenario, seed: int | None = None, noise: bool = True, registry=None,
                   where: str = "<scenario>", text: str | None = None, trajectory: Any = None) -> SimParts:
    """The recording of :func:`simulate` as data (before formatting). ``trajectory``: an already built
    trajectory of this scenario (it does not depend on the seed: a sweep builds it once for all seeds)."""
    seed = sc.seed if seed is None else int(seed)
    sims = build_simulators(sc, registry, where, text)
    if trajectory is None:
        if sc.duration is not None and sc.duration > MAX_DURATION_S:
            raise _document(sc, where, text).error(f"duration: {sc.duration:g} s; at most {MAX_DURATION_S:g} s "
                                                   "(a simulated recording is held in memory)")
        try:
            trajectory = build_trajectory(sc.trajectory, sc.dim, sc.duration)
        except TrajectoryError as exc:
            raise _document(sc, where, text).error(str(exc)) from None
        except MemoryError:
            raise _document(sc, where, text).error("trajectory: too long to sample in memory (a speed near 0 or "
                                                   "a huge duration or stop?)") from None
    traj = trajectory
    duration = float(sc.duration if sc.duration is not None else traj.duration)
    # every stream is held in memory before it is written: refuse sizes that cannot be, naming the field
    truth_rate = sc.truth.rate_hz or max((s.rate_hz() for s in sims.values()), default=10.0) or 10.0
    rates = [*((f"sensors.{n}.rate_hz", sm.rate_hz()) for n, sm in sims.items()), ("truth.rate_hz", truth_rate)]
    own = "" if sc.duration is not None else (
        f" (the trajectory's own length: {duration / 86400.0:.3g} days from its waypoints, speed and max_accel "
        f"{getattr(sc.trajectory, 'max_accel', '?')} m/s^2)" if duration > 86400.0 else " (the trajectory's own length)")
    for field_name, r in rates:
        if r and duration * r > MAX_SAMPLES:
            raise _document(sc, where, text).error(
                f"{field_name}: {r:g} Hz over {duration:g} s{own} is {duration * r:.3g} samples; at most "
                f"{MAX_SAMPLES:g} in one recording (lower the rate or split the duration)")
    lines = duration * sum(r for _, r in rates if r)
    if lines > MAX_LINES:
        raise _document(sc, where, text).error(
            f"duration: {duration:g} s{own} at {' + '.join(f'{r:g}' for _, r in rates if r)} Hz is {lines:.3g} "
            f"lines; at most {MAX_LINES:g} in one recording (it is held in memory: give a shorter duration, or "
            "simulate several with other seeds)")
    beacons = {k: np.array(v + [0.0] * (3 - len(v)), float) for k, v in sc.beacons.items()}
    origin = (sc.origin.lat_deg, sc.origin.lon_deg, sc.origin.alt_m) if sc.origin else None
    try:
        start = _dt.datetime.fromisoformat(sc.start_utc)
    except ValueError:
        raise ConfigError(f"{where}: start_utc: not an ISO date-time: {sc.start_utc!r}") from None

    header = [f"fusion-log {LOG_VERSION}", f"scenario: {sc.name}", f"seed: {seed}",
              f"noise: {'on' if noise else 'off'}"]
    if sc.description:
        header.append("description: " + " ".join(sc.description.split()))
    header += [f"duration: {duration:g}", f"dim: {sc.dim}", f"gravity: {sc.gravity:g}"]
    if origin is not None:
        header.append(f"origin: {origin[0]:.9f} {origin[1]:.9f} {origin[2]:.3f}")
        header.append(f"start_utc: {start.isoformat()}")
    for k, b in beacons.items():
        header.append(f"beacon {k}: {b[0]:g} {b[1]:g} {b[2]:g}")

    streams: list[SimStream] = []
    field_lines: list[str] = []
    for order, (name, sim) in enumerate(sims.items()):
        ctx = SimContext(traj, beacons, sc.dim, sc.gravity, duration, noise, sensor_rng(seed, name),
                         origin, start)
        try:
            out = sim.simulate(ctx)
            header += sim.header(ctx)
            field_lines.append(f"fields {name} " + " ".join(sim.fields(ctx)))
        except ConfigError as exc:
            raise _document(sc, where, text).error(str(exc)) from None
        prec = sim.params.precision or sc.precision
        streams.append(SimStream(name, order, np.asarray(out.t), out.values, prec))

    # truth at the highest sensor rate
    tt = sample_times(truth_rate, duration)
    kin = traj.sample(tt)
    if sc.dim == 2:
        names = ["px", "py", "vx", "vy"]
        cols = [kin.p[:, :2], kin.v[:, :2]]
    else:
        names = ["px", "py", "pz", "vx", "vy", "vz", "qw", "qx", "qy", "qz"]
        cols = [kin.p, kin.v, kin.q]
    for sim in sims.values():
        extra = sim.truth_fields()
        if extra and not set(extra) & set(names):
            names += list(extra)
            cols.append(np.asarray(sim.truth(tt), float).reshape(len(tt), len(extra)))
    field_lines.append("fields truth " + " ".join(names))
    streams.append(SimStream("truth", len(sims), tt, np.column_stack(cols), sc.truth.precision, True))
    return SimParts(header + field_lines, streams)


def render(parts: SimParts) -> str:
    """The log text of a simulated recording (see the module docstring)."""
    rows: list[tuple[int, int, str]] = []
    for st in parts.streams:
        name, order, prec = st.name, st.order, st.precision
        if st.table:
            for t, row in zip(st.t, st.values):
                rows.append((int(round(float(t) * 1e6)), order, format_line(float(t), name, row.tolist(),
                                                                            precision=prec)))
        else:
            for t, vals in zip(st.t, st.values):
                rows.append((int(round(float(t) * 1e6)), order, format_line(float(t), name, vals, precision=prec)))
    rows.sort(key=lambda r: (r[0], r[1]))
    lines = ["# " + h for h in parts.header] + [r[2] for r in rows]
    return "\n".join(lines) + "\n"


def simulate(sc: Scenario, seed: int | None = None, noise: bool = True, registry=None,
             where: str = "<scenario>", text: str | None = None) -> str:
    """The whole log text of a scenario (see the module docstring)."""
    return render(simulate_parts(sc, seed, noise, registry, where, text))


def simulate_file(path: str, seed: int | None = None, noise: bool = True, registry: Any = None) -> str:
    """Load a scenario file and simulate it."""
    from fusion.simulate.scenario import load_scenario
    sc, text = load_scenario(path)
    return simulate(sc, seed=seed, noise=noise, registry=registry, where=str(path), text=text)
