"""scipy's compiled LAPACK and BLAS wrappers, without the ~150 ms import of ``scipy.linalg``.

The filters and solvers call LAPACK and BLAS routines directly (``dpotrf``, ``dpotrs``, ``dtrtrs``,
``dgeqrf``, ``dtrsm``, ...): their matrices are tiny, so scipy's checking wrappers would cost more than
the flops (plugins/filters/linalg.py). Those routines live in two f2py extension modules of scipy,
``scipy.linalg._flapack`` and ``scipy.linalg._fblas``, which need only numpy. Importing them the usual way
first runs ``scipy/__init__`` and ``scipy/linalg/__init__``, which in scipy 1.15+ build the array-API
layer and import the whole of ``scipy.linalg``: ~150 ms on every ``fusion run``, against ~4 ms for the
two modules alone (``fusion run configs/abps_ins.yaml`` takes ~1 s in all, benchmarks/results/startup.md).

So :func:`_load` loads the two modules from scipy's own files with the standard library's extension
loader, under their own names. A later ``import scipy.linalg`` (a simulator, a plugin, a user's script)
imports them the ordinary way and gets the very same functions (CPython loads a shared library once),
so ``fusion.lapack.lapack.dpotrf is scipy.linalg.lapack.dpotrf``. Nothing is copied or patched. If the
files are not where scipy 1.x keeps them, or the direct load fails (e.g. a platform whose DLL search
path scipy's ``_distributor_init`` must set up first), the ordinary ``from scipy.linalg import lapack,
blas`` is used instead, with the same functions.

``lapack`` and ``blas`` are module objects; use them as ``scipy.linalg.lapack`` / ``scipy.linalg.blas``
(only the double-precision routines are used in this project).
"""
from __future__ import annotations

import importlib.machinery
import importlib.util
import os
import sys
from types import ModuleType

__all__ = ["lapack", "blas", "loaded_directly"]

_MODULES = ("_flapack", "_fblas")


def _load_extension(package_dir: str, name: str) -> ModuleType:
    full = f"scipy.linalg.{name}"
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        path = os.path.join(package_dir, name + suffix)
        if os.path.isfile(path):
            break
    else:
        raise ImportError(f"no extension file for {full} in {package_dir}")
    loader = importlib.machinery.ExtensionFileLoader(full, path)
    spec = importlib.util.spec_from_file_location(full, path, loader=loader)
    module = importlib.util.module_from_spec(spec)
    loader.exec_module(module)
    # The loader registers an extension module in sys.modules; take it out again, so that a later
    # ``import scipy.linalg`` imports it the ordinary way (and sets it as an attribute of its package).
    # CPython keeps a single-phase extension's module dict once loaded, so that import gets the same
    # function objects, not a second copy of the library.
    sys.modules.pop(full, None)
    return module


def _load() -> tuple[ModuleType, ModuleType, bool]:
    """(lapack, blas, loaded_directly)."""
    if "scipy.linalg" not in sys.modules:
        try:
            spec = importlib.util.find_spec("scipy")           # locates scipy without importing it
            if spec is not None and spec.submodule_search_locations:
                linalg_dir = os.path.join(list(spec.submodule_search_locations)[0], "linalg")
                flapack, fblas = (_load_extension(linalg_dir, name) for name in _MODULES)
                if hasattr(flapack, "dpotrf") and hasattr(fblas, "dtrsm"):
                    return flapack, fblas, True
        except (ImportError, OSError):
            pass
    from scipy.linalg import blas as scipy_blas, lapack as scipy_lapack
    return scipy_lapack, scipy_blas, False


lapack, blas, loaded_directly = _load()
