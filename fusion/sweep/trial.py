"""One trial of a sweep: simulate(scenario, seed), then run(config variant); a pure function of
(config, scenario, seed, filter, params, smooth), so its row does not depend on where it ran.

A ``param`` key is a dotted path into the system YAML (``process.spectral_density``,
``filter.alpha``, ``sensors.uwb.noise.sd``), or into the scenario when it starts with ``scenario.``
(``scenario.sensors.uwb.rate_hz``); a value is YAML (``0.2``, ``[1, 2]``, ``null``).
"""
from __future__ import annotations

import copy
import json
import math
import time
import traceback
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

from fusion.api import ConfigError

__all__ = ["Trial", "row_of", "health_columns", "run_trial", "system_of", "scenario_of", "recording_of", "drawn_mean",
           "drawn_from_truth", "with_initial", "METRICS", "HEALTH"]

#: The metric columns of a row, in order (``nis_mean_<sensor>`` columns follow, one per sensor).
METRICS = ("position_rmse_m", "position_max_m", "velocity_rmse_mps", "attitude_rmse_deg", "nees_mean",
           "nees_in_95_fraction", "estimates", "updates", "rejected", "late", "malformed", "resets",
           "not_positive_definite", "wall_s")
#: The health rule's judgement of a trial (fusion.health): ``degraded`` 1 or 0, ``health`` its findings.
HEALTH = ("degraded", "health")
SMOOTHED = ("smoothed_position_rmse_m", "smoothed_position_max_m", "smoothed_velocity_rmse_mps",
            "smoothed_nees_mean", "smoothed_nees_in_95_fraction")


@dataclass(frozen=True)
class Trial:
    """What a trial runs: paths of the system YAML and the scenario, the noise ``seed``, the ``filter``
    (None: the config's), ``params`` as sorted (key, YAML value text) pairs, ``smooth`` (RTS smoother
    after the forward filter), ``initial``: ``"config"`` (the config's initial mean, the same every
    seed) or ``"drawn"`` (the mean drawn per seed from N(true start, P0): the Monte-Carlo protocol of a
    NEES test, where the initial error is a draw of the initial covariance; see :func:`drawn_mean`)."""

    config: str
    scenario: str
    seed: int
    filter: str | None = None
    params: tuple[tuple[str, str], ...] = field(default_factory=tuple)
    smooth: bool = False
    initial: str = "config"

    def key(self) -> str:
        """Identity of the trial in a results file (resume): JSON of every field (``initial`` only when
        drawn, so results files written before it existed still resume)."""
        fields = [self.config, self.scenario, self.seed, self.filter or "", list(map(list, self.params)),
                  bool(self.smooth)]
        if self.initial != "config":
            fields.append(self.initial)
        return json.dumps(fields)

    def variant(self) -> tuple:
        """Everything but the seed: trials of one variant differ only in their noise."""
        return (self.config, self.scenario, self.filter, self.params, self.smooth, self.initial)


def _yaml_value(text: str, where: str) -> Any:
    import yaml

    from fusion.yamlsource import parse_yaml
    try:
        return parse_yaml(text)[0]
    except yaml.YAMLError:
        raise ConfigError(f"{where}: value {text!r} is not valid YAML") from None


def _set(data: dict, dotted: str, value: Any, where: str) -> None:
    """data[a][b][c] = value for ``a.b.c`` (missing mappings created)."""
    keys = dotted.split(".")
    node = data
    for i, k in enumerate(keys[:-1]):
        nxt = node.get(k) if isinstance(node, dict) else None
        if nxt is None:
            nxt = node[k] = {}
        elif isinstance(nxt, str) and k == "filter":   # filter: ukf -> {type: ukf}
            nxt = node[k] = {"type": nxt}
        elif not isinstance(nxt, dict):
            raise ConfigError(f"{where}: {'.'.join(keys[:i + 1])} is not a mapping (it is {nxt!r})")
        node = nxt
    node[keys[-1]] = value


@lru_cache(maxsize=64)
def _read_yaml(path: str) -> Any:
    from fusion.yamlsource import load_yaml
    return load_yaml(path).data


def _validation(where: str, exc: Any) -> ConfigError:
    err = exc.errors()[0]
    loc = ".".join(str(p) for p in err.get("loc", ()))
    return ConfigError(f"{where}: {loc + ': ' if loc else ''}{err.get('msg', exc)}")


def scenario_of(trial: Trial):
    """The validated fusion.simulate Scenario of a trial (its ``scenario.`` params applied)."""
    from pydantic import ValidationError

    from fusion.simulate.scenario import Scenario
    data = copy.deepcopy(_read_yaml(trial.scenario))
    if not isinstance(data, dict):
        raise ConfigError(f"{trial.scenario}: a scenario is a YAML mapping")
    data.setdefault("name", Path(trial.scenario).stem)
    for k, v in trial.params:
        if k.startswith("scenario."):
            _set(data, k[len("scenario."):], _yaml_value(v, f"--param {k}"), f"--param {k}")
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        with_ = " (with --param)" if any(k.startswith("scenario.") for k, _ in trial.params) else ""
        raise _validation(f"{trial.scenario}{with_}", exc) from None


def system_of(trial: Trial, lines: list[str] | None = None):
    """The wired System of a trial: the config with its params and filter (``filter`` other than the
    config's own type starts from that filter's defaults: the config's parameters belong to its filter),
    given the world its recording (``lines``, else the scenario's header) declares (fusion.world)."""
    from pydantic import ValidationError

    from fusion.config import SystemSpec, wire
    data = copy.deepcopy(_read_yaml(trial.config))
    if not isinstance(data, dict):
        raise ConfigError(f"{trial.config}: a system config is a YAML mapping")
    data["recording"] = None
    if trial.filter is not None:
        own = data.get("filter")
        own_type = own.get("type") if isinstance(own, dict) else own
        if trial.filter != own_type:
            data["filter"] = {"type": trial.filter}
    for k, v in trial.params:
        if not k.startswith("scenario."):
            _set(data, k, _yaml_value(v, f"--param {k}"), f"--param {k}")
    try:
        spec = SystemSpec.model_validate(data)
    except ValidationError as exc:
        given = [o for o, on in (("--param", any(not k.startswith("scenario.") for k, _ in trial.params)),
                                 ("--filter", trial.filter is not None)) if on]
        raise _validation(f"{trial.config}{' (with ' + '/'.join(given) + ')' if given else ''}", exc) from None
    try:
        from fusion.world import read_world_lines
        world = read_world_lines(lines if lines is not None else _scenario_header(trial), f"{trial.scenario} (simulated)")
        return wire(spec, path=Path(trial.config), world=world)
    except ConfigError as exc:
        given = [f"--param {k}={v}" for k, v in trial.params if not k.startswith("scenario.")]
        given += [f"--filter {trial.filter}"] if trial.filter is not None else []
        raise ConfigError(f"{trial.config}{' (with ' + ', '.join(given) + ')' if given else ''}: {exc}") from None


#: Seeds the initial-mean draw apart from the simulator's noise (the same stream for every filter).
INITIAL_STREAM = 1979660


def drawn_mean(system, lines: list[str], seed: int):
    """The initial mean of a ``drawn`` trial: the true state at the recording's first truth line plus a
    draw of N(0, P0) on the elements truth gives (other elements, and quaternion blocks, keep the
    config's mean), from ``numpy.random.default_rng([seed, INITIAL_STREAM])``. ConfigError when the
    recording has no truth to draw around."""
    from fusion.logformat import ParsedStream, iter_messages
    from fusion.api import Message

    st = ParsedStream()
    first = None
    for item in iter_messages(lines, st):
        if item.__class__ is Message and item.sensor == "truth":
            first = item
            break
    names = st.header.fields.get("truth")
    if first is None or not names:
        raise ConfigError("initial: drawn needs truth in the recording ('# fields truth ...' and a truth line)")
    return drawn_from_truth(system, names, first.values, seed)


def drawn_from_truth(system, names, first_values, seed: int):
    """:func:`drawn_mean` given the recording's truth field ``names`` and its first truth line's values."""
    import numpy as np

    layout = system.layout
    quat = {n for b in layout.blocks if b.kind == "quaternion" for n in b.element_names()}
    idx = [(layout.element_index(n), names.index(n)) for n in layout.names if n in names and n not in quat]
    if not idx:
        raise ConfigError("initial: drawn: no state element is named in the recording's truth fields")
    xi = np.array([i for i, _ in idx])
    truth = np.array([float(first_values[j]) for _, j in idx])
    L = np.linalg.cholesky(system.P0[np.ix_(xi, xi)])
    z = np.random.default_rng([int(seed), INITIAL_STREAM]).standard_normal(len(xi))
    x0 = np.array(system.x0, dtype=float)
    x0[xi] = truth + L @ z
    return x0


def with_initial(system, trial: Trial, lines: list[str] | None = None, truth: tuple | None = None):
    """``system`` with the trial's initial mean (itself unless ``initial`` is ``drawn``), drawn around the
    first truth line of the recording ``lines``, or of ``truth`` = (field names or None, first values or
    None) when the recording is already parsed."""
    if trial.initial == "config":
        return system
    if trial.initial != "drawn":
        raise ConfigError(f"initial {trial.initial!r}: expected 'config' or 'drawn'")
    import dataclasses

    if truth is not None:
        names, first = truth
        if first is None or not names:
            raise ConfigError("initial: drawn needs truth in the recording ('# fields truth ...' and a truth line)")
        return dataclasses.replace(system, x0=drawn_from_truth(system, names, first, trial.seed))
    return dataclasses.replace(system, x0=drawn_mean(system, lines, trial.seed))


def _scenario_header(trial: Trial) -> list[str]:
    """The header lines of a trial's scenario (what its recordings declare: field, receivers, beacons ...),
    simulated once per scenario and its ``scenario.`` params."""
    key = (trial.scenario, tuple(kv for kv in trial.params if kv[0].startswith("scenario.")))
    if key not in _HEADERS:
        from fusion.simulate import simulate
        try:
            lines = simulate(scenario_of(trial), seed=trial.seed).splitlines()
        except Exception:      # a broken scenario: said where the sweep simulates it, not here
            return []
        _HEADERS[key] = [ln for ln in lines[:20_000] if ln.startswith("#")] + [
            ln for ln in lines[:20_000] if ",$GP" in ln or ",$GN" in ln][:20]
    return _HEADERS[key]


_HEADERS: dict[tuple, list[str]] = {}


def recording_of(trial: Trial) -> list[str]:
    """The simulated recording of a trial, as lines (fusion.simulate, the trial's seed)."""
    from fusion.simulate import simulate
    return simulate(scenario_of(trial), seed=trial.seed).splitlines()


def _get(d: dict, *keys, default=math.nan):
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return default
        d = d[k]
    return d


def row_of(summary: dict, sensors: list[str]) -> dict[str, Any]:
    """The metric columns of a row from a run's summary (fusion.pipeline, DESIGN.md "Outputs")."""
    sens = summary.get("sensors", {})
    row = {
        "position_rmse_m": _get(summary, "errors", "position_rmse_m"),
        "position_max_m": _get(summary, "errors", "position_max_m"),
        "velocity_rmse_mps": _get(summary, "errors", "velocity_rmse_mps"),
        "attitude_rmse_deg": _get(summary, "errors", "attitude_rmse_deg"),
        "nees_mean": _get(summary, "consistency", "nees_mean"),
        "nees_in_95_fraction": _get(summary, "consistency", "nees_in_95_fraction"),
        "estimates": _get(summary, "errors", "samples", default=0),
        "updates": int(_get(summary, "steps", "update", default=0)),
        "rejected": sum(int(s.get("rejected", 0)) for s in sens.values()),
        "late": sum(int(s.get("late", 0)) for s in sens.values()),
        "malformed": sum(int(s.get("malformed", 0)) for s in sens.values()),
        "resets": int(_get(summary, "health", "resets", default=0)),
        "not_positive_definite": int(_get(summary, "filter_counters", "not_positive_definite", default=0)),
    }
    for s in sensors:
        row[f"nis_mean_{s}"] = _get(summary, "consistency", "nis_mean", s)
    sm = summary.get("smoothed")
    if sm is not None:
        row.update(smoothed_position_rmse_m=_get(sm, "errors", "position_rmse_m"),
                   smoothed_position_max_m=_get(sm, "errors", "position_max_m"),
                   smoothed_velocity_rmse_mps=_get(sm, "errors", "velocity_rmse_mps"),
                   smoothed_nees_mean=_get(sm, "consistency", "nees_mean"),
                   smoothed_nees_in_95_fraction=_get(sm, "consistency", "nees_in_95_fraction"))
    return row


def health_columns(system: Any, summary: dict, watch: Any = None, header: Any = None,
                   recording: Any = None) -> dict[str, Any]:
    """The HEALTH columns of a trial: the rule of ``fusion run`` (fusion.health) on its ``summary`` and its
    ``watch`` (a fusion.health.HealthWatch that saw the run's estimates, or a watch's report; None: from the
    summary alone, the shares and the errors against truth), written into the summary's ``health`` too.
    ``health`` is each finding's sensor and figures, ``; ``-joined (the causes, from the recording's parsed
    ``header`` and its ``recording`` lines, go to the summary's health)."""
    from fusion.health import assess

    verdict = assess(system, summary, watch, header, recording)
    text = "; ".join((f"{f.sensor}: " if f.sensor else "") + f.figures for f in verdict.findings)
    return {"degraded": int(verdict.degraded), "health": text}


def run_trial(trial: Trial) -> dict[str, Any]:
    """Simulate and run one trial through ``fusion.pipeline.run`` (or the smoother's run); its row. A
    failure is caught and recorded: ``status`` "error" and ``error`` the exception's one-line text."""
    t0 = time.perf_counter()
    try:
        lines = recording_of(trial)
        system = with_initial(system_of(trial, lines), trial, lines)
        from fusion.health import HealthWatch, spec_of
        watch = HealthWatch(system, spec_of(system))
        if trial.smooth:
            from fusion.smoothing.run import run_smoothed
            result = run_smoothed(system, lines, hooks=False, forward_sinks=[watch])
        else:
            from fusion import pipeline
            result = pipeline.run(system, lines, [watch], hooks=False)
        if result.interrupted:   # Ctrl-C, SIGTERM or SIGHUP (fusion.cli.stop_signals) mid-run: a cut trial is
            raise KeyboardInterrupt   # no row; the sweep stops, its rows so far kept (as between trials)
        row = row_of(result.summary, [n for n, s in system.sensors.items() if s.role == "measurement"])
        # a run that never initialised (e.g. a scenario without the config's sensors) is no result: a failed
        # row that says why, so the summary counts it, rather than "ok" with nothing in it
        not_started = result.summary.get("not_started")
        if not not_started:
            row.update(health_columns(system, result.summary, watch, result.parsed.header, lines))
        row.update(status="error" if not_started else "ok", error=not_started or "", engine="pipeline",
                   wall_s=time.perf_counter() - t0)
        return row
    except Exception as exc:  # a failed trial is a row, the sweep goes on
        msg = f"{type(exc).__name__}: {exc}".replace("\n", " ")
        return {"status": "error", "error": msg[:500], "engine": "pipeline", "wall_s": time.perf_counter() - t0,
                "traceback": traceback.format_exc(limit=3)[-1000:]}
