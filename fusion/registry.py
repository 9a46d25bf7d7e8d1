"""Plugin registry on pluggy: built-ins through the same register() as third parties, then entry points.

    pm = PluginManager("fusion"); pm.add_hookspecs(fusion.hookspecs)
    register the built-in modules; pm.load_setuptools_entrypoints("fusion"); pm.check_pending()

``FUSION_DISABLE_PLUGIN_AUTOLOAD=1`` skips third-party entry points; ``FUSION_BLOCK_PLUGINS=a,b``
blocks plugins by name (entry-point name or built-in module name).
"""
from __future__ import annotations

import difflib
import functools
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
        self._lazy: dict[str, dict[str, tuple[str, str]]] = {k: {} for k in KINDS}  # name -> (target, provider)
        self.providers: dict[str, str] = {}  # top-level package -> "distribution version"
        self.pm: pluggy.PluginManager | None = None  # set by make_plugin_manager

    def provider_of(self, cls: type) -> str:
        """Who provides ``cls``: its distribution and version, or the built-in label."""
        top = cls.__module__.split(".")[0]
        return self.providers.get(top) or _builtin_provider()

    def add(self, cls: type[Component], name: str | None = None) -> None:
        """Register a component class under its ``kind`` and ``name`` (or the given name)."""
        kind, nm = cls.kind, name or cls.name
        if kind not in self._entries:
            raise ValueError(f"{cls.__qualname__}: unknown kind {kind!r}; kinds are {list(KINDS)}")
        if not nm:
            raise ValueError(f"{cls.__qualname__}: component has no name")
        if nm in self._lazy[kind]:
            self._resolve(kind, nm)
        prev = self._entries[kind].get(nm)
        provider = self.provider_of(cls)
        if prev is not None and prev.cls is not cls:
            raise ValueError(f"{kind} {nm!r} registered twice: by {prev.provider} and {provider}")
        self._entries[kind][nm] = Entry(kind, nm, cls, provider)

    def add_lazy(self, kind: str, name: str, target: str) -> None:
        """Register ``"package.module:ClassName"`` as ``kind`` ``name`` without importing it: the module is
        imported when the component is first asked for (``get``, ``entries``). For components whose
        imports are heavy and that most commands never use (the simulators: only ``fusion simulate``)."""
        if kind not in self._lazy:
            raise ValueError(f"{target}: unknown kind {kind!r}; kinds are {list(KINDS)}")
        if name in self._entries[kind] or name in self._lazy[kind]:
            raise ValueError(f"{kind} {name!r} registered twice")
        top = target.split(".")[0]
        self._lazy[kind][name] = (target, self.providers.get(top) or _builtin_provider())

    def _resolve(self, kind: str, name: str) -> None:
        target, provider = self._lazy[kind].pop(name)
        modname, _, attr = target.partition(":")
        cls = getattr(importlib.import_module(modname), attr)
        if cls.kind != kind or (cls.name and cls.name != name):
            raise ValueError(f"{target}: registered lazily as {kind} {name!r} but declares {cls.kind} {cls.name!r}")
        self._entries[kind][name] = Entry(kind, name, cls, provider)

    def names(self, kind: str) -> list[str]:
        return sorted([*self._entries[kind], *self._lazy[kind]])

    def entries(self, kind: str | None = None) -> list[Entry]:
        kinds = [kind] if kind else list(KINDS)
        for k in kinds:
            for n in list(self._lazy[k]):
                self._resolve(k, n)
        return [self._entries[k][n] for k in kinds for n in sorted(self._entries[k])]

    def get(self, kind: str, name: str, where: str = "") -> type[Component]:
        """The class of ``kind`` named ``name``; ConfigError listing known names and a "did you mean"."""
        if name in self._lazy.get(kind, ()):
            self._resolve(kind, name)
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
    """Set up the plugin manager and fill a Registry from every plugin (built-in, entry points, extra).

    The PluginManager is kept (``registry.pm``) so the observation hooks (``fusion_on_estimate``, ...) can
    be called through ``pm.hook`` during a run."""
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
    try:
        pm.check_pending()
    except pluggy.PluginValidationError as exc:
        raise _misspelt_hook(pm, exc) from None
    # Each component is attributed to the distribution of the plugin module whose top-level package
    # defines its class (a plugin's classes live in its own package).
    registry.providers = {}
    for plugin, dist in pm.list_plugin_distinfo():
        top = getattr(plugin, "__name__", "").split(".")[0]
        if top and top not in ("fusion", "fusion_plugins"):
            registry.providers[top] = f"{dist.metadata['name']} {dist.version}"
    registry.pm = pm
    pm.hook.fusion_register_components(registry=registry)
    return pm, registry


def _misspelt_hook(pm: pluggy.PluginManager, exc: pluggy.PluginValidationError) -> ConfigError:
    """A hookimpl with no spec (a misspelt hook name) as one line a user can act on: which hook, where
    (file:line), which plugin and package, the hook it probably means, and how to run without it."""
    import inspect

    plugin = exc.plugin
    name = pm.get_name(plugin) or getattr(plugin, "__name__", repr(plugin))
    dists = {id(p): f"{d.metadata['name']} {d.version}" for p, d in pm.list_plugin_distinfo()}
    package = dists.get(id(plugin))
    specs = [h for h in dir(hookspecs) if h.startswith("fusion_")]
    parts = []
    for impl in pm.get_hookcallers(plugin) or []:
        if impl.spec is not None:
            continue
        where = ""
        for hi in impl.get_hookimpls():
            if hi.plugin is plugin:
                fn = inspect.unwrap(hi.function)
                try:
                    where = f"{inspect.getsourcefile(fn)}:{inspect.getsourcelines(fn)[1]}: "
                except (OSError, TypeError):
                    where = ""
        close = difflib.get_close_matches(impl.name, specs, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        parts.append(f"{where}hook {impl.name!r} is not a fusion hook{hint}")
    what = "; ".join(parts) or str(exc)
    source = f"plugin {name!r} of the installed package {package!r}" if package else f"plugin {name!r}"
    return ConfigError(f"{what}: in {source}; fix or uninstall it, or run with FUSION_BLOCK_PLUGINS={name} "
                       "(FUSION_DISABLE_PLUGIN_AUTOLOAD=1 skips every third-party plugin)")


@functools.lru_cache(maxsize=1)
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
