"""Plugin registry on pluggy: built-ins through the same register() as third parties, then entry points.

    pm = PluginManager("fusion"); pm.add_hookspecs(fusion.hookspecs)
    register the built-in modules; pm.load_setuptools_entrypoints("fusion"); pm.check_pending()

``FUSION_DISABLE_PLUGIN_AUTOLOAD=1`` skips third-party entry points; ``FUSION_BLOCK_PLUGINS=a,b``
blocks plugins by name (entry-point name or built-in module name).
"""
from __future__ import annotations

import difflib
import importlib
import importlib.metadata as md
import os
from dataclasses import dataclass
from typing import Iterable

import pluggy

from fusion import hookspecs
from fusion.api import KINDS, ConfigError, Component

# Built-in plugin modules (pytest's default_plugins pattern), by the same names as their entry points in
# pyproject.toml, so load_setuptools_entrypoints() sees them registered and does not load them twice.
# Each has a hookimpl fusion_register_components. A missing module is skipped.
BUILTIN_PLUGINS: dict[str, str] = {
    "sources": "fusion.sources",
    "sinks": "fusion.sinks",
    "decoders": "fusion_plugins.decoders",
    "filters": "fusion_plugins.filters",
    "gates": "fusion_plugins.gates",
    "measurement": "fusion_plugins.measurement",
    "process": "fusion_plugins.process",
    "solvers": "fusion_plugins.solvers",
    "simulators": "fusion_plugins.simulators",
    "importers": "fusion.importers",
}


@dataclass(frozen=True)
class Entry:
    """A registered component class and who provides it."""

    kind: str
    name: str
    cls: type[Component]
    provider: str  # "distribution version" or "builtin"


class Registry:
    """name -> component class, per kind."""

    def __init__(self) -> None:
        self._entries: dict[str, dict[str, Entry]] = {k: {} for k in KINDS}
        self._provider = "builtin"

    def add(self, cls: type[Component], name: str | None = None) -> None:
        """Register a component class under its ``kind`` and ``name`` (or the given name)."""
        kind, nm = cls.kind, name or cls.name
        if kind not in self._entries:
            raise ValueError(f"{cls.__qualname__}: unknown kind {kind!r}; kinds are {list(KINDS)}")
        if not nm:
            raise ValueError(f"{cls.__qualname__}: component has no name")
        prev = self._entries[kind].get(nm)
        if prev is not None and prev.cls is not cls:
            raise ValueError(f"{kind} {nm!r} registered twice: by {prev.provider} and {self._provider}")
        self._entries[kind][nm] = Entry(kind, nm, cls, self._provider)

    def names(self, kind: str) -> list[str]:
        return sorted(self._entries[kind])

    def entries(self, kind: str | None = None) -> list[Entry]:
        kinds = [kind] if kind else list(KINDS)
        return [self._entries[k][n] for k in kinds for n in sorted(self._entries[k])]

    def get(self, kind: str, name: str, where: str = "") -> type[Component]:
        """The class of ``kind`` named ``name``; ConfigError listing known names and a "did you mean"."""
        try:
            return self._entries[kind][name].cls
        except KeyError:
            known = self.names(kind)
            close = difflib.get_close_matches(str(name), known, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            at = f"{where}: " if where else ""
            raise ConfigError(f"{at}unknown {kind} {name!r}{hint} (known {kind}s: {', '.join(known) or 'none'})") from None


def _blocked() -> set[str]:
    return {s.strip() for s in os.environ.get("FUSION_BLOCK_PLUGINS", "").split(",") if s.strip()}


def make_plugin_manager(extra_plugins: Iterable[object] = ()) -> tuple[pluggy.PluginManager, Registry]:
    """Set up the plugin manager and fill a Registry from every plugin (built-in, entry points, extra)."""
    pm = pluggy.PluginManager("fusion")
    pm.add_hookspecs(hookspecs)
    registry = Registry()
    blocked = _blocked()
    for name in blocked:
        pm.set_blocked(name)
    for short, modname in BUILTIN_PLUGINS.items():
        if short in blocked or modname in blocked:
            continue
        try:
            mod = importlib.import_module(modname)
        except ModuleNotFoundError as exc:
            if exc.name == modname:
                continue
            raise
        pm.register(mod, name=short)
    if not os.environ.get("FUSION_DISABLE_PLUGIN_AUTOLOAD"):
        pm.load_setuptools_entrypoints("fusion")
    for plugin in extra_plugins:
        pm.register(plugin)
    pm.check_pending()

    # Call each implementation ourselves so every component is attributed to its distribution.
    dist_of = {id(p): dist for p, dist in pm.list_plugin_distinfo()}
    for impl in pm.hook.fusion_register_components.get_hookimpls():
        dist = dist_of.get(id(impl.plugin))
        registry._provider = f"{dist.metadata['name']} {dist.version}" if dist is not None else _builtin_provider()
        impl.function(registry=registry)
    registry._provider = "builtin"
    return pm, registry


def _builtin_provider() -> str:
    try:
        return f"fusion-estimator {md.version('fusion-estimator')} (built-in)"
    except md.PackageNotFoundError:
        return "fusion (built-in)"


_DEFAULT: Registry | None = None


def default_registry() -> Registry:
    """The process-wide registry (built once, on first use)."""
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = make_plugin_manager()[1]
    return _DEFAULT
