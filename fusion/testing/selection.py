"""Choosing and building registered components for tests: all of a kind, or only one package's."""
from __future__ import annotations

from typing import Any

from fusion.api import BuildContext, Component

__all__ = ["registered", "registry_class", "build", "parametrize_registered"]


def registered(kind: str, package: str | None = None) -> list[str]:
    """Names of the registered components of ``kind``; with ``package`` (a top-level import name such as
    ``"fusion_baro"``), only those whose class is defined in it: an author's suite then tests the
    author's components, never someone else's installed ones."""
    from fusion.registry import default_registry

    reg = default_registry()
    if package is None:
        return reg.names(kind)
    return [e.name for e in reg.entries(kind) if e.cls.__module__.split(".")[0] == package]


def build(kind: str, name: str, params: dict[str, Any] | None = None,
          context: BuildContext | None = None) -> Component:
    """Build a registered component from a params dict (validated by its Params model). Errors propagate."""
    from fusion.registry import default_registry

    cls = default_registry().get(kind, name)
    return cls(cls.Params(**(params or {})), context)


def parametrize_registered(kind: str, argname: str = "name", package: str | None = None):
    """``pytest.mark.parametrize(argname, registered(kind, package))`` (imports pytest). Pass your
    package so that only your components are parametrised."""
    import pytest

    return pytest.mark.parametrize(argname, registered(kind, package))


def registry_class(kind: str, name: str) -> type[Component]:
    """The registered class of ``kind`` named ``name`` (for the ``check_*`` calls)."""
    from fusion.registry import default_registry

    return default_registry().get(kind, name)
