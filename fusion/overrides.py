"""Command-line overrides of a config: ``--filter NAME`` and ``--filter-param KEY=VALUE`` (run and tui)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from fusion.api import ConfigError
from fusion.yamlsource import load_yaml, parse_yaml, yaml_problem


def filter_override(config: str | Path, name: str | None, params: list[str]) -> Any:
    """The filter spec after --filter/--filter-param (None when neither is given). Only --filter-param
    without --filter reads the config, to start from its own filter spec. A VALUE is YAML (``alpha=0.5``,
    ``beta=[1, 2]``); ConfigError, in one line, for an item that is not KEY=VALUE or a VALUE that is not
    YAML (``alpha=[1``)."""
    if name is None and not params:
        return None
    base: dict[str, Any]
    if name is not None:
        base = {"type": name}
    else:
        own = load_yaml(config).data.get("filter", "ekf")
        base = {"type": own} if isinstance(own, str) else dict(own) if isinstance(own, dict) else {"type": own}
    for item in params:
        key, sep, value = item.partition("=")
        key = key.strip()
        shown = repr(item) if len(item) <= 60 else repr(item[:57] + "...")
        if not sep or not key:
            raise ConfigError(f"--filter-param {shown}: expected KEY=VALUE (e.g. alpha=0.5)")
        try:
            parsed, _ = parse_yaml(value)
        except yaml.YAMLError as exc:
            _, problem = yaml_problem(exc)
            raise ConfigError(f"--filter-param {shown}: VALUE is not valid YAML ({problem}); e.g. alpha=0.5, "
                              "beta=[1, 2], name=text") from None
        base[key] = parsed
    return base
