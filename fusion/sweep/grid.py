"""The trials of a sweep (seeds x filters x parameter values) and :func:`sweep`, the whole sweep as an
API: run what the results file does not have yet, append rows as they finish, return every row."""
from __future__ import annotations

import itertools
import re
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

from fusion.api import ConfigError

from .trial import Trial

__all__ = ["split_values", "parse_params", "trials_of", "default_scenario", "sweep", "latest"]


def split_values(text: str) -> list[str]:
    """``v1,v2,...`` split at the commas outside brackets and quotes (so ``[1, 2],[3, 4]`` is two values)."""
    out, depth, cur, quote = [], 0, "", None
    for ch in text:
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            out.append(cur.strip())
            cur = ""
            continue
        cur += ch
    out.append(cur.strip())
    return out


def parse_params(items: Sequence[str]) -> list[tuple[str, list[str]]]:
    """``--param key=v1,v2`` items as (key, values); ConfigError for a malformed one."""
    out = []
    for item in items:
        key, sep, vals = item.partition("=")
        key = key.strip()
        if not sep or not key or not re.fullmatch(r"[A-Za-z_][\w.-]*", key) or not vals.strip():
            raise ConfigError(f"--param {item!r}: expected KEY=V1,V2,... with KEY a dotted path into the config "
                              "(e.g. process.spectral_density=0.1,0.2 or scenario.sensors.uwb.rate_hz=5,1)")
        if any(k == key for k, _ in out):
            raise ConfigError(f"--param {key}: given twice; give all its values in one --param")
        values = split_values(vals)
        if any(v == "" for v in values):
            raise ConfigError(f"--param {item!r}: an empty value")
        out.append((key, values))
    return out


def default_scenario(config: str) -> str:
    """The scenario that made the config's own recording (its ``# scenario: NAME`` header, looked up as
    scenarios/NAME.yaml beside the config's folder); ConfigError when there is none."""
    from fusion.yamlsource import load_yaml

    data = load_yaml(config).data
    rec = data.get("recording") if isinstance(data, dict) else None
    if rec:
        p = (Path(config).parent / rec)
        if p.exists():
            with open(p, encoding="utf-8", errors="replace") as fh:
                for line in itertools.islice(fh, 40):
                    m = re.match(r"#\s*scenario:\s*(\S+)", line)
                    if m:
                        for base in (Path(config).parent.parent, Path.cwd()):
                            cand = base / "scenarios" / f"{m.group(1)}.yaml"
                            if cand.exists():
                                return str(cand)
    raise ConfigError(f"{config}: no scenario to simulate: give --scenario SCENARIO.yaml (the config's recording "
                      "names none that exists under scenarios/)")


def trials_of(config: str, scenario: str, seeds: Iterable[int], filters: Sequence[str | None],
              params: Sequence[tuple[str, list[str]]], smooth: bool = False, initial: str = "config") -> list[Trial]:
    """Every combination, seeds innermost (so a variant's seeds are together); ``initial`` as Trial's."""
    keys = [k for k, _ in params]
    out = []
    for flt in filters:
        for combo in itertools.product(*[v for _, v in params]):
            ps = tuple(sorted(zip(keys, combo)))
            for s in seeds:
                out.append(Trial(config, scenario, int(s), flt, ps, smooth, initial))
    return out


def latest(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per trial key, the last one written (a retried trial replaces its failure)."""
    by: dict[str, dict] = {}
    for r in rows:
        by[r["key"]] = r
    return list(by.values())


def sweep(trials: list[Trial], out: str | Path, engine: str = "auto", jobs: int = 2, dask: str | None = None,
          progress: Callable[[int, int], Any] | None = None, sensors: Sequence[str] | None = None) -> tuple[list[dict], dict]:
    """Run the trials the results file ``out`` lacks (.csv appended as they finish, .parquet written at
    the end) and return (every row of the sweep, info: engine used per trial count, skipped, reasons).

    ``engine``: auto (batch for the variants that support it, their chunks over ``jobs`` processes, then a
    pool for the rest; with ``dask`` the rest goes to the cluster), batch (all in this process), serial,
    pool, dask."""
    from . import engines
    from .results import CsvWriter, check_output, columns, done_keys, read_rows, trial_fields, write_parquet
    from .trial import system_of

    out = Path(out)
    check_output(str(out), sorted({p for t in trials for p in (t.config, t.scenario)}))
    if engine not in engines.ENGINES:
        raise ConfigError(f"--engine {engine!r}: one of {', '.join(engines.ENGINES)}")
    variants = {t.variant(): t for t in trials}
    sensor_names: list[str] = list(sensors or [])
    from .trial import scenario_of
    from fusion.simulate.engine import build_simulators
    for t in variants.values():       # every variant wires and its scenario validates: bad input before any run
        system = system_of(t)
        # the sensor simulators' parameters too (sensors.uwb.rate_hz=0 would be an error row in every trial)
        build_simulators(scenario_of(t), where=f"{t.scenario}"
                         + (" (with --param)" if any(k.startswith("scenario.") for k, _ in t.params) else ""))
        for n, s in system.sensors.items():
            if s.role == "measurement" and n not in sensor_names:
                sensor_names.append(n)
    keys = sorted({k for t in trials for k, _ in t.params})
    cols = columns(keys, sensor_names, any(t.smooth for t in trials))
    previous = read_rows(out)
    done = done_keys(previous)
    todo = [t for t in trials if t.key() not in done]
    info = {"skipped": len(trials) - len(todo), "engines": {}, "not_batched": {}}
    writer = CsvWriter(out, cols) if out.suffix == ".csv" else None
    new_rows: list[dict] = []
    client = None
    try:
        streams = []
        if engine in ("auto", "batch"):
            ready, rest, why = engines.batch_ready(todo)
            info["not_batched"] = why
            streams.append(engines.run_batched(ready, jobs=1 if engine == "batch" else jobs))
            if engine == "batch" and rest:
                streams.append(engines.run_serial(rest))
            elif rest:
                if dask:
                    client = engines.dask_client(dask, jobs)
                    streams.append(engines.run_dask(rest, client))
                else:
                    streams.append(engines.run_pool(rest, jobs) if jobs > 1 else engines.run_serial(rest))
        elif engine == "serial":
            streams.append(engines.run_serial(todo))
        elif engine == "pool":
            streams.append(engines.run_pool(todo, jobs))
        else:
            client = engines.dask_client(dask or "local", jobs)
            streams.append(engines.run_dask(todo, client))
        n = 0
        if progress:
            progress(0, len(todo))
        for trial, row in itertools.chain(*streams):
            full = {**trial_fields(trial), **row}
            new_rows.append(full)
            e = row.get("engine", "?")
            info["engines"][e] = info["engines"].get(e, 0) + 1
            if writer is not None:
                writer.write(full)
            n += 1
            if progress:
                progress(n, len(todo))
    finally:
        if writer is not None:
            writer.close()
        if out.suffix == ".parquet" and (new_rows or not out.exists()):
            write_parquet(out, latest(previous + new_rows), cols)
        if client is not None:
            cluster = getattr(client, "cluster", None)
            client.close()
            if cluster is not None:
                cluster.close()
    wanted = {t.key() for t in trials}
    rows = [r for r in latest(previous + new_rows) if r["key"] in wanted]
    return rows, info

