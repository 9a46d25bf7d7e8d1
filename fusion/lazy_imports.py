"""Start-up trims the CLI applies before its imports (never on import of the library): defer the numpy
submodules that scipy's import touches but nothing in a ``fusion`` command uses, and give PyYAML's reader a
cheaply compiled copy of its one expensive regular expression (:func:`cheap_yaml_reader`).

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
import re
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


#: PyYAML's ``Reader.NON_PRINTABLE`` as yaml/reader.py spells it: the characters outside the printable set,
#: as a negated class whose ranges span all of Unicode.
YAML_NON_PRINTABLE = "[^\x09\x0A\x0D\x20-\x7E\x85\xA0-\uD7FF\uE000-\uFFFD\U00010000-\U0010ffff]"
#: The same set of characters written as the ranges it consists of (the complement of the printable ranges
#: within U+0000..U+10FFFF): the same matches for every code point (tests/core/test_lazy_yaml_regex.py).
YAML_NON_PRINTABLE_RANGES = "[\x00-\x08\x0B\x0C\x0E-\x1F\x7F-\x84\x86-\x9F\uD800-\uDFFF\uFFFE\uFFFF]"


def cheap_yaml_reader() -> None:
    """Before the first ``import yaml``: yaml/reader.py compiles :data:`YAML_NON_PRINTABLE` at import, and
    the re module takes ~60M instructions (~8 ms, as much as the rest of yaml's import) to compile a negated
    class that spans all of Unicode; :data:`YAML_NON_PRINTABLE_RANGES`, the same characters, compiles in
    ~0.4 ms. It is put in the re module's cache under yaml's text, so yaml's ``re.compile`` returns it.
    Nothing happens when yaml is already imported or the cache is not the dict it is in CPython 3.11-3.13
    (yaml then compiles its own, as before); a cache that overflows before yaml's import drops it the same way."""
    cache = getattr(re, "_cache", None)
    if "yaml" in sys.modules or not isinstance(cache, dict):
        return
    key = (str, YAML_NON_PRINTABLE, 0)
    if key not in cache:
        cache[key] = re.compile(YAML_NON_PRINTABLE_RANGES)
