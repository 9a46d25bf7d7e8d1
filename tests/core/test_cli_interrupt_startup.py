"""Ctrl-C while the ``fusion`` command is still importing its modules (not a KeyboardInterrupt
traceback and exit 1) is one line and exit 130, as later in a run."""
import subprocess
import sys

import pytest

from fusion import cli, console


class _InterruptImport:
    """A meta-path finder that raises KeyboardInterrupt when ``name`` is imported (where Ctrl-C lands)."""

    def __init__(self, name):
        self.name = name

    def find_spec(self, fullname, path=None, target=None):
        if fullname == self.name:
            raise KeyboardInterrupt
        return None


def test_ctrl_c_while_the_entry_imports_the_command_line(monkeypatch, capsys):
    monkeypatch.delitem(sys.modules, "fusion.cli")
    monkeypatch.setattr(sys, "meta_path", [_InterruptImport("fusion.cli"), *sys.meta_path])
    assert console.main(["--help"]) == 130
    err = capsys.readouterr().err
    assert err == "interrupted\n"


def test_ctrl_c_while_the_commands_are_imported(monkeypatch, capsys):
    def interrupted_build():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted_build)
    assert cli.main(["validate", "configs/abps_ins.yaml"]) == 130
    assert capsys.readouterr().err == "interrupted\n"


def test_the_entry_module_imports_nothing_heavy():
    """``import fusion.console`` (the console script's first import) loads no third-party module, so the
    window before its KeyboardInterrupt handler is the interpreter's own start-up."""
    code = ("import sys; before = set(sys.modules); import fusion.console; "
            "print(sorted(m for m in set(sys.modules) - before if not m.startswith('fusion')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    new = eval(out)
    assert not any(m.split(".")[0] in {"pluggy", "numpy", "pydantic", "yaml", "scipy"} for m in new), new


def test_hookimpl_is_still_importable_from_the_package():
    from fusion import hookimpl, hookspec
    import fusion.hookspecs

    assert hookimpl is fusion.hookspecs.hookimpl and hookspec is fusion.hookspecs.hookspec
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        import fusion
        fusion.nothing  # noqa: B018
