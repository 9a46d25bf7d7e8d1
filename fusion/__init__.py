"""fusion: plugin-based sensor fusion. ``from fusion import hookimpl`` to write a plugin."""
from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from fusion.hookspecs import hookimpl, hookspec

__all__ = ["hookimpl", "hookspec", "__version__"]
__version__ = "0.1.0"


def __getattr__(name: str):
    # ``hookimpl`` / ``hookspec`` on first use: importing pluggy is not needed before a command
    # wires plugins, and the ``fusion`` entry (fusion.console) must start before anything heavy
    if name in ("hookimpl", "hookspec"):
        from fusion import hookspecs

        return getattr(hookspecs, name)
    raise AttributeError(f"module 'fusion' has no attribute {name!r}")
