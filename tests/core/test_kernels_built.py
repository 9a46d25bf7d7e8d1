"""The compiled kernels (setup.py ``KERNELS``) are built and loaded where the project is installed with a
C compiler, as in CI: a kernel that silently failed to build would leave every kernel-against-numpy test
comparing the numpy code with itself. Set ``FUSION_ALLOW_MISSING_KERNELS=1`` to install and test without a
compiler (the numpy code then runs everywhere: tested by the same suite)."""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from fusion import kernels

SETUP = Path(__file__).resolve().parents[2] / "setup.py"


def declared_kernels() -> dict[str, str]:
    """setup.py's KERNELS dict (module name -> C source), read without running setup.py."""
    for node in ast.parse(SETUP.read_text()).body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "KERNELS" for t in node.targets):
            return ast.literal_eval(node.value)
    raise AssertionError("setup.py has no KERNELS dict")


def test_setup_declares_every_kernel_a_plugin_loads():
    """A kernel a plugin loads but setup.py does not declare is never built (the plugin silently on numpy)."""
    loaded = set()
    for src in (SETUP.parent / "plugins").rglob("*.py"):
        loaded |= set(re.findall(r'kernels\.load\("([\w.]+)"\)', src.read_text()))
    assert loaded and loaded == set(declared_kernels())


@pytest.mark.parametrize("name", sorted(declared_kernels()))
def test_every_declared_kernel_is_built(name, monkeypatch):
    assert (SETUP.parent / declared_kernels()[name]).is_file(), f"{name}: its C source is missing"
    monkeypatch.delenv("FUSION_PURE_PYTHON", raising=False)
    module = kernels.load(name)
    if module is None and kernels.missing_allowed():
        pytest.skip(f"{name} not built (FUSION_ALLOW_MISSING_KERNELS)")
    assert module is not None, (f"{name} is declared in setup.py but not importable: the optional build failed "
                                "(a C compiler and Python's headers are needed; see pip's build log)")


def test_pure_python_switch_hides_every_kernel(monkeypatch):
    for value, off in (("1", True), ("yes", True), ("0", False), ("", False)):
        monkeypatch.setenv("FUSION_PURE_PYTHON", value)
        assert kernels.disabled() is off
        for name in declared_kernels():
            if off:
                assert kernels.load(name) is None
            else:
                module = kernels.load(name)
                assert module is None or module.__name__ == name


def test_an_unknown_kernel_is_none(monkeypatch):
    monkeypatch.delenv("FUSION_PURE_PYTHON", raising=False)
    assert kernels.load("fusion_plugins.no_such_kernel") is None
