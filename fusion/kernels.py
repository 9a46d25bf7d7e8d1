"""Optional compiled kernels of the built-in plugins (setup.py ``KERNELS``).

A kernel is a C extension module that mirrors one numpy function of a plugin exactly in its maths (the
same operations, possibly in another order, so the same numbers to rounding: ~1e-15 relative). It exists
only where the numpy version is dominated by per-call overhead on tiny arrays that no library vectorises
away (DESIGN.md, performance notes). The numpy version stays the reference: the tests run both and compare.

:func:`load` returns the module, or None when it was not built (no C compiler at install: setup.py marks
every kernel optional) or when ``FUSION_PURE_PYTHON=1`` is set, in which case the plugin uses its numpy code.
"""
from __future__ import annotations

import importlib
import os
from types import ModuleType

__all__ = ["load", "disabled", "missing_allowed"]


def disabled() -> bool:
    """True when ``FUSION_PURE_PYTHON`` is set to anything but '' or '0': every plugin uses its numpy code."""
    return os.environ.get("FUSION_PURE_PYTHON", "") not in ("", "0")


def missing_allowed() -> bool:
    """True when ``FUSION_ALLOW_MISSING_KERNELS`` is set (to anything but '' or '0'): the test suite may then
    skip the tests of a kernel that is not loaded (no C compiler at install, or ``FUSION_PURE_PYTHON=1``);
    otherwise a kernel that is not loaded fails them, so that an install whose build failed is noticed."""
    return os.environ.get("FUSION_ALLOW_MISSING_KERNELS", "") not in ("", "0")


def load(name: str) -> ModuleType | None:
    """The compiled module ``name`` (e.g. ``"fusion_plugins.process._ins_run_kernel"``), or None when it is
    not installed or kernels are disabled (:func:`disabled`)."""
    if disabled():
        return None
    try:
        return importlib.import_module(name)
    except ImportError:
        return None
