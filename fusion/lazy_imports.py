"""The start-up trim the CLI applies before its imports (never on import of the library): defer the numpy
submodules that scipy's import touches but nothing in a ``fusion`` command uses.

Since scipy 1.15, ``import scipy.linalg`` runs its vendored array-api-compat, which clones numpy's
namespace attribute by attribute (``array_api_compat._internal.clone_module``) and so imports every
lazily loaded numpy submodule, ``numpy.testing`` and ``numpy.f2py`` among them: ~45 ms of the ~1 s that
``fusion run configs/abps_ins.yaml`` takes, for modules no command calls. Registering them with the
standard library's :class:`importlib.util.LazyLoader` first makes them real modules that execute on
first attribute access, so code that does use them (a plugin calling ``numpy.testing``) behaves as
before. Called by the CLI only, never on import of the library: a program that imports ``fusion`` keeps
its own import order.
"""
from __future__ import annotations

import importlib.util
import sys

DEFERRED = ("numpy.testing", "numpy.f2py")


def defer_unused_numpy_modules() -> None:
    """Make :data:`DEFERRED` lazy unless they are already imported (imports numpy, not them)."""
    for name in DEFERRED:
        if name in sys.modules:
            continue
        try:
            spec = importlib.util.find_spec(name)
        except (ImportError, ValueError):
            continue
        if spec is None or spec.loader is None:
            continue
        loader = importlib.util.LazyLoader(spec.loader)
        spec.loader = loader
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        loader.exec_module(module)
        parent, _, child = name.rpartition(".")
        setattr(sys.modules[parent], child, module)  # numpy.__getattr__ would otherwise import it again

