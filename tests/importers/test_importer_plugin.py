"""Importers are a plugin kind: a third party's importer, registered through the same hook as any plugin,
is chosen by its suffix (or --format) and its streams are written like the built-ins'."""
from __future__ import annotations

import numpy as np

import fusion.registry as registry_mod
from import_helpers import Recording, fusion_import, one_error_line
from fusion import hookimpl
from fusion.api import ImportedLog, Importer, Stream


class TwoColumns(Importer):
    """A toy format: 't value' per line."""

    name = "twocol"
    suffixes = (".two",)
    sensors = ("alt",)

    def read(self, path, request):
        data = np.loadtxt(path, ndmin=2)
        log = ImportedLog(meta={"source": f"{path} (two columns)"})
        keep = np.ones(len(data), bool) if request.start is None else data[:, 0] >= request.start
        log.streams.append(Stream("alt", ("h",), data[keep, 0], data[keep, 1:2]))
        return log


class Plugin:
    @hookimpl
    def fusion_register_components(self, registry):
        registry.add(TwoColumns)


def test_third_party_importer_by_suffix_and_by_name(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(registry_mod, "_DEFAULT", registry_mod.make_plugin_manager([Plugin()])[1])
    src = tmp_path / "baro.two"
    src.write_text("0.0 10.5\n0.5 10.75\n1.0 11.0\n")
    assert fusion_import(src, "-o", tmp_path / "a.log", "--start", "0.25") == 0
    rec = Recording(tmp_path / "a.log")
    np.testing.assert_allclose(rec.times("alt"), [0.5, 1.0])
    np.testing.assert_allclose(rec.values("alt")[:, 0], [10.75, 11.0])
    capsys.readouterr()
    other = tmp_path / "baro.dat"
    other.write_text("0.0 1.0\n")
    assert fusion_import(other, "-o", tmp_path / "b.log") == 2
    assert "twocol" in one_error_line(capsys)          # the error lists the known suffixes, the plugin's too
    assert fusion_import(other, "-o", tmp_path / "b.log", "--format", "twocol") == 0
