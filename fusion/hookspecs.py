"""Hook specifications: with fusion.api, the only API a plugin author needs.

A plugin is a module (or object) with functions marked ``@fusion.hookimpl`` whose names match these
specs; ``check_pending()`` rejects a misspelt hook name at start-up.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import pluggy

if TYPE_CHECKING:
    from fusion.registry import Registry

hookspec = pluggy.HookspecMarker("fusion")
hookimpl = pluggy.HookimplMarker("fusion")


@hookspec
def fusion_register_components(registry: "Registry") -> None:
    """Add this plugin's components to the registry.

    Called once per plugin when the plugin manager is set up (fusion.registry.make_plugin_manager).

    :param registry: call ``registry.add(ComponentClass)`` for each component; the class declares its
        ``kind`` (process, measurement, filter, gate, decoder, solver, source, sink, simulator), ``name``,
        pydantic ``Params`` and docstring.
    """
