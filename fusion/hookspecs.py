"""Hook specifications: with fusion.api, the only API a plugin author needs.

A plugin is a module (or object) with functions marked ``@fusion.hookimpl`` whose names match these
specs; ``check_pending()`` rejects a misspelt hook name at start-up.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import pluggy

if TYPE_CHECKING:
    from fusion.api import Estimate, Event
    from fusion.config import System
    from fusion.registry import Registry

hookspec = pluggy.HookspecMarker("fusion")
hookimpl = pluggy.HookimplMarker("fusion")


@hookspec
def fusion_register_components(registry: "Registry") -> None:
    """Add this plugin's components to the registry.

    Called once per plugin when the plugin manager is set up (fusion.registry.make_plugin_manager).

    :param registry: call ``registry.add(ComponentClass)`` for each component; the class declares its
        ``kind`` (process, measurement, filter, gate, decoder, solver, source, sink, simulator), ``name``,
        pydantic ``Params`` and docstring. A ``source`` declares the URL ``schemes`` and/or file
        ``suffixes`` it reads (``fusion run --input udp://...``), a ``sink`` the ``suffixes`` it writes
        (``fusion run --output run.tsv``).
    """


# --------------------------------------------------------------------------- observation hooks
# Called by fusion.pipeline during a run, through the kept PluginManager (``registry.pm.hook``), for every
# registered plugin that implements them. They observe: the return value is ignored, and an implementation
# that raises cannot end the run: it is not called again, the run goes on complete, and the failure, naming
# the plugin, is in ``RunResult.plugin_errors`` and the summary's ``plugin_errors`` (``fusion run`` writes
# its outputs, prints one line per failure and exits 2). Each is called only when some plugin implements
# it, so a run without observers pays nothing.
# Which runs call them: ``fusion run``, ``fusion tui`` and ``fusion.pipeline.run`` / ``Run`` (unless given
# ``hooks=False``). The trials of ``fusion sweep`` do not (serial, pooled and batched alike: they run with
# ``hooks=False``, fusion/sweep/trial.py and batched.py): a sweep is thousands of runs, and its results file
# is what watches it.


@hookspec
def fusion_on_estimate(estimate: "Estimate", system: "System") -> None:
    """Called for every estimate a run emits, in time order, after the run's own sinks got it.
    Not called by the trials of ``fusion sweep`` (``hooks=False``), nor by a ``pipeline.run(..., hooks=False)``.

    :param estimate: the ``fusion.api.Estimate`` (``t`` s, ``belief`` with ``x`` and ``cov``, ``reason``
        ``update`` or ``output``, ``sensor``, and ``update`` with the innovation and NIS). Immutable: keep
        what you need, do not modify it.
    :param system: the wired system being run (read its ``layout`` to name the state elements).
    """


@hookspec
def fusion_on_event(event: "Event", system: "System") -> None:
    """Called for every event of a run (``malformed``, ``late``, ``rejected``, ``gap``, ``warning``,
    ``no_fix``, ...), as it happens.
    Not called by the trials of ``fusion sweep`` (``hooks=False``), nor by a ``pipeline.run(..., hooks=False)``.

    :param event: the ``fusion.api.Event`` (``t`` s or NaN, ``kind``, ``sensor`` or None, ``detail``).
    :param system: the wired system being run.
    """


@hookspec
def fusion_on_run_end(summary: dict, system: "System") -> None:
    """Called once when a run ends (end of input, a lost source, Ctrl-C, or ``q`` in ``fusion tui``), with its
    summary.
    Not called by the trials of ``fusion sweep`` (``hooks=False``), nor by a ``pipeline.run(..., hooks=False)``.

    :param summary: a copy of the summary dict ``--summary-json`` writes (DESIGN.md "Outputs"): editing it
        changes neither the printed table nor the file.
    :param system: the wired system that was run.
    """
