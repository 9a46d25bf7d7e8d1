"""The observers of a run that are not the run's own: the plugins' observation hooks (:class:`Observers`) and
sinks, which see read-only copies (:func:`read_only`) and cannot end the run (a failure is named, and its
outputs discarded)."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from fusion.api import Belief, Estimate, FusionError, UpdateResult

if TYPE_CHECKING:
    from fusion.run.session import Run

__all__ = ["Observers", "PASSED_ON", "read_only", "is_own", "discard_outputs"]


#: What an observer's failure is not: a FusionError (the user's to fix: a failed write, raised as before) and
#: a BrokenPipeError (a plugin printing to a stdout whose reader went away: the CLI ends quietly, exit 141).
PASSED_ON = (FusionError, BrokenPipeError)


class Observers:
    """The implementations of one observation hook, called one by one in pluggy's order (the last
    registered first): one that raises is named in the run's ``plugin_errors`` and not called again, the
    others and the run go on (an observer cannot end the run, nor lose its outputs: tester6 #10)."""

    def __init__(self, name: str, impls: list[tuple[Callable, tuple[str, ...] | None, str]], run: "Run"):
        self.name = name
        self.impls = impls
        self.run = run

    @classmethod
    def of(cls, pm: Any, registry: Any, name: str, run: "Run") -> "Observers | None":
        """The hook's implementations, None when there is none."""
        found = getattr(pm.hook, name).get_hookimpls()
        if not found:
            return None
        if any(hi.hookwrapper or getattr(hi, "wrapper", False) for hi in found):
            hook = getattr(pm.hook, name)   # a wrapper needs pluggy's own call; one failure is still named
            return cls(name, [(hook, None, f"a plugin's {name} hook")], run)
        providers = getattr(registry, "providers", {}) or {}
        impls = []
        for hi in reversed(found):
            impls.append((hi.function, tuple(hi.argnames), plugin_label(pm, hi.plugin, providers)))
        return cls(name, impls, run)

    def __call__(self, **kwargs: Any) -> None:
        for impl in self.impls:
            fn, names, who = impl
            try:
                if names is None:
                    fn(**kwargs)
                else:
                    fn(*[kwargs[a] for a in names])
            except PASSED_ON:
                raise
            except Exception as exc:
                self._failed(impl, exc, kwargs)

    def _failed(self, impl: tuple, exc: BaseException, kwargs: dict[str, Any]) -> None:
        self.impls = [i for i in self.impls if i is not impl]
        item = kwargs.get("estimate", kwargs.get("event"))
        t = getattr(item, "t", math.nan)
        at = f" at t = {t:.3f} s" if isinstance(t, float) and math.isfinite(t) else (
            " at the end of the run" if self.name == "fusion_on_run_end" else "")
        again = "" if self.name == "fusion_on_run_end" else "; it was not called again"
        self.run.plugin_failed(f"{impl[2]}: its {self.name} hook raised {type(exc).__name__}: {exc}{at}{again}", exc)
        if not self.impls:    # none left: the run stops copying estimates for it
            self.run.observers_gone(self)


def plugin_label(pm: Any, plugin: Any, providers: dict[str, str]) -> str:
    """``plugin t6 (fusion-t6 0.1.0)``: the entry point's name and the distribution that installed it."""
    name = pm.get_name(plugin) or ""
    if not name or name.isdigit():   # registered without a name (pluggy names it by id): its module or class
        name = getattr(plugin, "__name__", None) or type(plugin).__qualname__
    top = (getattr(plugin, "__name__", None) or type(plugin).__module__).split(".")[0]
    package = providers.get(top)
    return f"plugin {name}" + (f" ({package})" if package else "")


def discard_outputs(sink: Any) -> list[str]:
    """Discard the ``fusion.api.OutputFile`` objects a (failed) sink holds as attributes; their paths."""
    from fusion.outputs import OutputFile

    paths = []
    for value in list(getattr(sink, "__dict__", {}).values()):
        if isinstance(value, OutputFile):
            if value.temporary is not None or value.file is not None:
                paths.append(value.path)
            value.discard()
    return paths


def is_own(sink: Any) -> bool:
    """A sink of fusion itself (its CSV, JSON lines, plot and summary sinks, or their wrappers): trusted not to
    write into the arrays it is given; any other (a plugin's) gets read-only copies."""
    inner = getattr(sink, "sink", sink)      # guard_sink and similar wrappers keep the sink they guard
    mod = type(inner).__module__
    return mod == "fusion" or mod.startswith("fusion.")


def frozen(a: Any) -> Any:
    if isinstance(a, np.ndarray):
        a = a.copy()
        a.flags.writeable = False
    return a


def read_only(estimate: Estimate) -> Estimate:
    """A copy of ``estimate`` whose arrays (the belief's x, P or S; the update's innovation and S) are
    read-only: what an observation hook or a plugin's sink is given (docs/writing-plugins.md: the objects
    are immutable). A hook that wrote into ``estimate.belief.x`` wrote into the filter's own state, and every
    later estimate started from it (tester3 #13: RMSE 0.11 m -> 693 km, exit 0); now it raises
    ``ValueError: assignment destination is read-only`` in the plugin, named by the run."""
    b = estimate.belief
    belief = Belief(b.t, frozen(b.x), P=frozen(b.P), S=frozen(b.S), events=b.events)
    u = estimate.update
    if u is not None:
        u = UpdateResult(belief if u.belief is b else u.belief, frozen(u.innovation), frozen(u.S), u.nis,
                         u.accepted, events=u.events, iterations=u.iterations)
    return Estimate(estimate.t, belief, estimate.reason, estimate.sensor, u)
