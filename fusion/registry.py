"""Plugin registry on pluggy: built-ins through the same register() as third parties, then entry points.

    pm = PluginManager("fusion"); pm.add_hookspecs(fusion.hookspecs)
    register the built-in modules; pm.load_setuptools_entrypoints("fusion"); pm.check_pending()

``FUSION_DISABLE_PLUGIN_AUTOLOAD=1`` skips third-party entry points; ``FUSION_BLOCK_PLUGINS=a,b``
blocks plugins by name (entry-point name or built-in module name).

A broken installed plugin never stops what does not use it. A plugin whose module fails to import, whose
hook names are misspelt or whose ``fusion_register_components`` raises is left out and kept in
``Registry.broken`` (:class:`Problem`: which plugin, which package, where, what, how to block it); a name it
registers twice (a built-in's) or lazily with a bad target is refused, the first registration kept, and
asking for that name is a ConfigError with the same facts; asking for an unknown name names the broken
plugins that might have provided it. ``default_registry()`` reports each broken plugin once as a
:class:`PluginWarning` (the CLI prints it as one line, ``fusion run: warning: ...``) and ``fusion plugins``
lists them (exit code 2).
"""
from __future__ import annotations

import difflib
import functools
import importlib
import importlib.metadata as md
import os
import re
import sys
import traceback
import warnings
from dataclasses import dataclass
from typing import Iterable

import pluggy

from fusion import hookspecs
from fusion.api import KINDS, ConfigError, Component, Params

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


class PluginWarning(UserWarning):
    """An installed plugin is broken and left out (its module fails to import, a hook is misspelt, its
    registration fails); the components that do not need it still work."""


@dataclass(frozen=True)
class Problem:
    """A broken plugin, or one name a plugin could not register: ``plugin`` (its entry-point or built-in
    name: what FUSION_BLOCK_PLUGINS takes), ``package`` ("distribution version", or None), ``what`` (where
    and what went wrong, one line), ``kind``/``name`` (the component, when the problem is one name)."""

    plugin: str
    package: str | None
    what: str
    kind: str | None = None
    name: str | None = None

    @property
    def source(self) -> str:
        return (f"plugin {self.plugin!r} of the installed package {self.package!r}" if self.package
                else f"plugin {self.plugin!r}")

    @property
    def way_out(self) -> str:
        return (f"fix or uninstall it, or run with FUSION_BLOCK_PLUGINS={self.plugin} "
                "(FUSION_DISABLE_PLUGIN_AUTOLOAD=1 skips every third-party plugin)")

    def message(self) -> str:
        """One line: what, where, which plugin and package, and how to run without it."""
        return f"{self.what}: in {self.source}; {self.way_out}"


class Registry:
    """name -> component class, per kind."""

    def __init__(self) -> None:
        self._entries: dict[str, dict[str, Entry]] = {k: {} for k in KINDS}
        # name -> (target, provider, plugin, "file:line: " of the add_lazy call): plugin is the name of the
        # plugin that registered it (or None)
        self._lazy: dict[str, dict[str, tuple[str, str, str | None, str]]] = {k: {} for k in KINDS}
        self.providers: dict[str, str] = {}  # top-level package -> "distribution version"
        self.pm: pluggy.PluginManager | None = None  # set by make_plugin_manager
        #: Broken plugins and refused names (fusion.registry.Problem), in the order found.
        self.broken: list[Problem] = []
        self._refused: dict[tuple[str, str], Problem] = {}   # (kind, name) -> why asking for it fails
        # While make_plugin_manager calls a plugin's fusion_register_components: (plugin, package); a name
        # it cannot register is then recorded as a Problem instead of raised.
        self._loading: tuple[str, str | None] | None = None

    def provider_of(self, cls: type) -> str:
        """Who provides ``cls``: its distribution and version, or the built-in label."""
        top = cls.__module__.split(".")[0]
        return self.providers.get(top) or _builtin_provider()

    def add(self, cls: type[Component], name: str | None = None) -> None:
        """Register a component class under its ``kind`` and ``name`` (or the given name)."""
        if self._loading is not None:
            self._lenient(self._add, cls, name, kind=getattr(cls, "kind", None), name=name or getattr(cls, "name", None))
            return
        self._add(cls, name)

    def add_lazy(self, kind: str, name: str, target: str) -> None:
        """Register ``"package.module:ClassName"`` as ``kind`` ``name`` without importing it: the module is
        imported when the component is first asked for (``get``, ``entries``). For components whose
        imports are heavy and that most commands never use (the simulators: only ``fusion simulate``)."""
        if self._loading is not None:
            self._lenient(self._add_lazy, kind, name, target, kind=kind, name=name)
            return
        self._add_lazy(kind, name, target)

    def _lenient(self, fn, *args, kind, name) -> None:
        """``fn(*args)`` for the plugin being loaded: a ValueError (a name registered twice, an unknown
        kind) is recorded as that plugin's Problem, the first registration kept."""
        try:
            fn(*args)
        except ValueError as exc:
            plugin, package = self._loading  # type: ignore[misc]
            problem = Problem(plugin, package, f"{_caller()}{exc}", kind, name)
            self.broken.append(problem)
            if kind in self._entries and name and (kind, name) not in self._refused:
                self._refused[(kind, name)] = problem

    def _add(self, cls: type[Component], name: str | None = None) -> None:
        if not (isinstance(cls, type) and issubclass(cls, Component)):
            raise ValueError(f"{cls!r} is not a component class (a subclass of one of the fusion.api bases: "
                             "ProcessModel, MeasurementModel, Gate, ...)")
        kind, nm = cls.kind, name or cls.name
        if kind not in self._entries:
            raise ValueError(f"{cls.__qualname__}: unknown kind {kind!r}; kinds are {list(KINDS)}")
        if not nm:
            raise ValueError(f"{cls.__qualname__}: component has no name")
        self._check_name(kind, nm, cls.__qualname__)
        _check_params(kind, nm, cls)
        if nm in self._lazy[kind]:
            self._resolve(kind, nm)
        prev = self._entries[kind].get(nm)
        provider = self.provider_of(cls)
        if prev is not None and prev.cls is not cls:
            raise ValueError(f"{kind} {nm!r} registered twice: by {prev.provider} and {provider}")
        if kind in ("source", "sink"):
            self._check_claims(kind, nm, cls, provider)
        self._entries[kind][nm] = Entry(kind, nm, cls, provider)

    def _check_name(self, kind: str, name: object, who: str) -> None:
        """A name a config can write and tell apart: an identifier (never a module path, never a space), and
        not another registered name of its kind but for case (``ranGE`` next to the built-in ``range``)."""
        if not isinstance(name, str) or not NAME.match(name):
            raise ValueError(f"{who}: {kind} name {name!r} is not a registry name (an ASCII letter or _, then "
                             "letters, digits or _, e.g. 'my_baro'; never a module path)")
        folded = name.lower()
        for other in (*self._entries[kind], *self._lazy[kind]):
            if other != name and other.lower() == folded:
                raise ValueError(f"{who}: {kind} {name!r} differs from the registered {kind} {other!r} only in case: "
                                 "a config could not tell them apart, so it is not registered (give it a name of "
                                 "its own)")

    def _check_claims(self, kind: str, name: str, cls: type, provider: str) -> None:
        """A URL scheme or file suffix already claimed by another source (sink) is refused, as a name
        registered twice is: otherwise which one reads ``file://`` (writes ``.csv``) would depend on the
        order plugins load in, and a plugin could silently take over a built-in's input."""
        for other in self._entries[kind].values():
            if other.cls is cls:
                continue
            for attr, fmt in (("schemes", "{}://"), ("suffixes", "{}")):
                both = sorted(set(getattr(cls, attr, ())) & set(getattr(other.cls, attr, ())))
                if both:
                    claimed = ", ".join(fmt.format(s) for s in both)
                    raise ValueError(f"{kind} {name!r} ({provider}) claims {claimed}, already {kind == 'source' and 'read' or 'written'} "
                                     f"by {kind} {other.name!r} ({other.provider}): ambiguous, so {name!r} is not registered "
                                     "(give it a scheme or suffix of its own)")

    def _add_lazy(self, kind: str, name: str, target: str) -> None:
        if kind not in self._lazy:
            raise ValueError(f"{target}: unknown kind {kind!r}; kinds are {list(KINDS)}")
        self._check_name(kind, name, target)
        if name in self._entries[kind] or name in self._lazy[kind]:
            prev = self._entries[kind].get(name)
            by = prev.provider if prev is not None else self._lazy[kind][name][1]
            raise ValueError(f"{kind} {name!r} registered twice: by {by} and {target}")
        top = target.split(".")[0]
        plugin = self._loading[0] if self._loading is not None else None
        self._lazy[kind][name] = (target, self.providers.get(top) or _builtin_provider(), plugin, _caller())

    def _resolve(self, kind: str, name: str) -> None:
        """Import a lazily registered component. A target that cannot be imported, lacks the class or
        declares another kind or name is refused (a Problem of its plugin), never raised here: ``get``
        then explains it, ``entries`` leaves it out."""
        target, provider, plugin, called = self._lazy[kind].pop(name)
        modname, _, attr = target.partition(":")
        try:
            cls = getattr(importlib.import_module(modname), attr)
            if getattr(cls, "kind", None) != kind or (cls.name and cls.name != name):
                raise ValueError(f"registered lazily as {kind} {name!r} but declares {getattr(cls, 'kind', None)} "
                                 f"{getattr(cls, 'name', None)!r}")
            _check_params(kind, name, cls)
        except Exception as exc:  # a broken plugin: whatever its module raises
            what = str(exc) if isinstance(exc, ValueError) else f"{_where(exc, modname)}{type(exc).__name__}: {exc}"
            package = None if provider.endswith("(built-in)") else provider
            problem = Problem(plugin or modname.split(".")[0], package,
                              f"{called}{kind} {name!r} = {target!r} cannot be loaded: {what}", kind, name)
            self.broken.append(problem)
            self._refused[(kind, name)] = problem
            return
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
        at = f"{where}: " if where else ""
        refused = self._refused.get((kind, name))
        if refused is not None:
            raise ConfigError(f"{at}{refused.message()}")
        try:
            return self._entries[kind][name].cls
        except KeyError:
            known = self.names(kind)
            close = difflib.get_close_matches(str(name), known, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            broken = [p for p in self.broken if p.name is None]
            also = "".join(f"; {p.source} could not be loaded and may provide it ({p.what}): {p.way_out}"
                           for p in broken)
            kinds = f"{kind}es" if kind.endswith("s") else f"{kind}s"      # 'process' -> 'processes'
            raise ConfigError(f"{at}unknown {kind} {name!r}{hint} (known {kinds}: {', '.join(known) or 'none'})"
                              f"{also}") from None


#: A component's registry name: what a config writes (``model: my_baro``), never a module path.
NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_BUILTIN_TOPS = ("fusion", "fusion_plugins")


def _check_params(kind: str, name: str, cls: type) -> None:
    """ValueError unless ``cls.Params`` is a class deriving from fusion.api.Params that forbids unknown keys
    (a plain pydantic model would silently ignore a misspelt key), and, for a third-party class, every plain
    default of it is a valid value of its field (``limit: float = "nine"`` would pass ``fusion validate``
    and fail the run). Built-in classes are held to the same by the test suite, not at every start."""
    P = getattr(cls, "Params", None)
    who = f"{kind} {name!r}"
    if not isinstance(P, type):
        raise ValueError(f"{who}: Params must be a class deriving from fusion.api.Params, got {P!r}")
    if not issubclass(P, Params):
        raise ValueError(f"{who}: its Params ({P.__qualname__}) does not derive from fusion.api.Params: unknown "
                         "(misspelt) keys would be accepted silently")
    if P.model_config.get("extra") != "forbid":
        raise ValueError(f"{who}: its Params ({P.__qualname__}) does not forbid unknown keys (model_config extra="
                         f"{P.model_config.get('extra')!r}; fusion.api.Params sets 'forbid'): a misspelt key would be "
                         "accepted silently")
    if cls.__module__.split(".")[0] not in _BUILTIN_TOPS:
        bad = params_default_errors(P)
        if bad:
            raise ValueError(f"{who}: a default of its Params ({P.__qualname__}) is not a valid value: {bad}")


def params_default_errors(P: type[Params]) -> str:
    """Why the plain defaults of the Params model ``P`` are not valid values of their fields ("" when they
    are): ``field = default: error`` for each, joined by ``; ``. A None default (the usual "not given") and
    default factories are not checked; a model validator's cross-field rules are not either."""
    from pydantic import ValidationError

    defaults = {}
    for n, f in P.model_fields.items():
        if not f.is_required() and f.default_factory is None and f.default is not None:
            defaults[f.alias or n] = f.default
    if not defaults:
        return ""
    try:
        P.model_validate(defaults)
    except ValidationError as exc:
        errors = [e for e in exc.errors() if e["loc"] and e["loc"][0] in defaults and e["type"] != "missing"]
        return "; ".join(f"{'.'.join(map(str, e['loc']))} = {defaults[e['loc'][0]]!r}: {e['msg']}" for e in errors)
    except Exception as exc:   # a validator of the plugin's that raises something else
        return f"validating the defaults raised {type(exc).__name__}: {exc}"
    return ""


def _blocked() -> set[str]:
    return {s.strip() for s in os.environ.get("FUSION_BLOCK_PLUGINS", "").split(",") if s.strip()}


def make_plugin_manager(extra_plugins: Iterable[object] = ()) -> tuple[pluggy.PluginManager, Registry]:
    """Set up the plugin manager and fill a Registry from every plugin (built-in, entry points, extra).

    The PluginManager is kept (``registry.pm``) so the observation hooks (``fusion_on_estimate``, ...) can
    be called through ``pm.hook`` during a run. A broken installed plugin (a module that fails to import, a
    misspelt hook, a registration that raises) is left out and recorded in ``registry.broken``; one of
    ``extra_plugins`` (the caller's own code) with a misspelt hook is a ConfigError."""
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
    builtin = set(pm.get_plugins())
    packages: dict[int, str] = {}   # id(plugin) -> "distribution version", for the entry-point plugins
    if not os.environ.get("FUSION_DISABLE_PLUGIN_AUTOLOAD"):
        _load_entry_points(pm, registry, packages)
    for plugin in extra_plugins:
        pm.register(plugin)
    try:
        pm.check_pending()
    except pluggy.PluginValidationError as exc:
        if id(exc.plugin) not in packages:
            raise _misspelt_hook(pm, exc, packages) from None
        _set_aside(pm, registry, exc.plugin, packages, _misspelt_hook(pm, exc, packages, problem=True))
        _check_rest(pm, registry, packages)
    # Each component is attributed to the distribution of the plugin module whose top-level package
    # defines its class (a plugin's classes live in its own package).
    registry.providers = {}
    for plugin in pm.get_plugins():
        top = getattr(plugin, "__name__", "").split(".")[0]
        if id(plugin) in packages and top and top not in ("fusion", "fusion_plugins"):
            registry.providers[top] = packages[id(plugin)]
    registry.pm = pm
    # Each plugin's registration on its own, the built-ins first (a third party cannot take a built-in's
    # name), in pluggy's order otherwise; a name one cannot register, or an exception, is its Problem.
    impls = pm.hook.fusion_register_components.get_hookimpls()[::-1]
    impls.sort(key=lambda hi: hi.plugin not in builtin)
    for hi in impls:
        if hi.hookwrapper or getattr(hi, "wrapper", False):
            continue
        name = pm.get_name(hi.plugin) or getattr(hi.plugin, "__name__", repr(hi.plugin))
        package = packages.get(id(hi.plugin))
        registry._loading = (name, package)
        try:
            hi.function(**{a: registry for a in hi.argnames})
        except Exception as exc:  # a broken plugin: whatever its hook raises
            if hi.plugin in builtin or id(hi.plugin) not in packages:
                raise
            registry.broken.append(Problem(name, package, f"{_where(exc, _top(hi.plugin))}fusion_register_components "
                                                          f"raised {type(exc).__name__}: {exc}"))
        finally:
            registry._loading = None
    return pm, registry


def _top(plugin: object) -> str:
    return getattr(plugin, "__name__", "").split(".")[0]


def _load_entry_points(pm: pluggy.PluginManager, registry: Registry, packages: dict[int, str]) -> None:
    """pluggy's ``load_setuptools_entrypoints("fusion")``, one entry point at a time: one whose module
    fails to import, or that pluggy refuses, is a Problem of its plugin instead of the end of every
    command."""
    for dist in list(md.distributions()):
        for ep in dist.entry_points:
            if ep.group != "fusion" or pm.get_plugin(ep.name) or pm.is_blocked(ep.name):
                continue
            package = f"{dist.metadata['name']} {dist.version}"
            try:
                plugin = ep.load()
                pm.register(plugin, name=ep.name)
            except Exception as exc:  # a broken plugin: whatever its import raises
                pm.set_blocked(ep.name)     # not loaded again (and pluggy's own loading would skip it)
                top = ep.value.split(":")[0].split(".")[0]
                registry.broken.append(Problem(ep.name, package, f"{_where(exc, top)}its module {ep.value!r} "
                                                                 f"cannot be imported: {type(exc).__name__}: {exc}"))
                continue
            packages[id(plugin)] = package


def _set_aside(pm: pluggy.PluginManager, registry: Registry, plugin: object, packages: dict[int, str],
               problem: "Problem") -> None:
    registry.broken.append(problem)
    name = pm.get_name(plugin)
    pm.unregister(plugin)
    if name:
        pm.set_blocked(name)
    packages.pop(id(plugin), None)


def _check_rest(pm: pluggy.PluginManager, registry: Registry, packages: dict[int, str]) -> None:
    """check_pending again after setting a plugin aside, until none is left with a misspelt hook."""
    while True:
        try:
            pm.check_pending()
            return
        except pluggy.PluginValidationError as exc:
            if id(exc.plugin) not in packages:
                raise _misspelt_hook(pm, exc, packages) from None
            _set_aside(pm, registry, exc.plugin, packages, _misspelt_hook(pm, exc, packages, problem=True))


def _caller() -> str:
    """``file:line: `` of the first frame outside this module (the plugin's call to ``registry.add``)."""
    f = sys._getframe(1)
    while f is not None and f.f_code.co_filename == __file__:
        f = f.f_back
    return f"{f.f_code.co_filename}:{f.f_lineno}: " if f is not None else ""


def _where(exc: BaseException, top: str) -> str:
    """``file:line: `` of the innermost traceback frame in the plugin's package ``top`` (else the
    innermost outside importlib and pluggy), or ``""``."""
    frames = traceback.extract_tb(exc.__traceback__)
    if isinstance(exc, SyntaxError) and exc.filename:
        return f"{exc.filename}:{exc.lineno}: "
    sep = os.sep
    mine = [f for f in frames if f"{sep}{top}{sep}" in f.filename or f.filename.endswith(f"{sep}{top}.py")]
    rest = [f for f in frames if "importlib" not in f.filename and f"{sep}pluggy{sep}" not in f.filename
            and not f.filename.startswith("<") and f.filename != __file__]
    pick = (mine or rest or [None])[-1]
    return f"{pick.filename}:{pick.lineno}: " if pick is not None else ""


def _misspelt_hook(pm: pluggy.PluginManager, exc: pluggy.PluginValidationError, packages: dict[int, str],
                   problem: bool = False):
    """A hookimpl with no spec (a misspelt hook name) as one line a user can act on: which hook, where
    (file:line), which plugin and package, the hook it probably means, and how to run without it (a
    ConfigError, or with ``problem`` the Problem of an installed plugin)."""
    import inspect

    plugin = exc.plugin
    name = pm.get_name(plugin) or getattr(plugin, "__name__", repr(plugin))
    package = packages.get(id(plugin))
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
    found = Problem(name, package, what)
    return found if problem else ConfigError(found.message())


@functools.lru_cache(maxsize=1)
def _builtin_provider() -> str:
    try:
        return f"fusion-estimator {md.version('fusion-estimator')} (built-in)"
    except md.PackageNotFoundError:
        return "fusion (built-in)"


_DEFAULT: Registry | None = None


def default_registry(warn: bool = True) -> Registry:
    """The process-wide registry (built once, on first use). When it is built, each broken plugin found
    is reported as a :class:`PluginWarning` (unless ``warn`` is False: ``fusion plugins`` lists them)."""
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = make_plugin_manager()[1]
        if warn:
            warn_broken(_DEFAULT)
    return _DEFAULT


def warn_broken(registry: Registry) -> None:
    """One PluginWarning per broken plugin or refused name of ``registry``: what, where, which package,
    how to run without it; the components that do not need it still work."""
    for p in registry.broken:
        what = (f"a config using {p.kind} {p.name!r} is refused" if p.name else "its components are unavailable")
        warnings.warn(f"{p.source} is broken ({p.what}); {what}, the rest works; {p.way_out}", PluginWarning,
                      stacklevel=2)
