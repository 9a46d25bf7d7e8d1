"""fusion: plugin-based sensor fusion. ``from fusion import hookimpl`` to write a plugin."""
from fusion.hookspecs import hookimpl, hookspec

__all__ = ["hookimpl", "hookspec", "__version__"]
__version__ = "0.1.0"
