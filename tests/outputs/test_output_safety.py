"""Outputs never destroy an input or leave a cut file, whatever the path or the failure (tester findings of
the output rules): an input named by a URL or read by a plugin's source, full disks (``/dev/full``, an
ENOSPC injected into a temporary file), ``-o -`` and closed pipes, an empty ``--input``, the permission
bits of a replaced file."""
from __future__ import annotations

import errno
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from fusion.api import Params, Source
from fusion.cli import main

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"


@pytest.fixture
def work(tmp_path):
    """A config with a short recording of its own (400 lines of the shipped one), in a temporary folder."""
    rec = tmp_path / "walk.log"
    rec.write_text("".join((ROOT / "recordings" / "example_2d.log").read_text().splitlines(True)[:400]))
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(CONFIG.read_text().replace("../recordings/example_2d.log", "walk.log"))
    return tmp_path, cfg, rec


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


# --------------------------------------------------------------------------- 1. inputs through URLs, plugins
@pytest.mark.parametrize("form", ["file://{abs}", "FILE://{abs}", "file://localhost{abs}"])
def test_an_input_named_by_a_file_url_is_never_overwritten(work, form, capsys):
    tmp, cfg, walk = work
    rec = tmp / "rec.jsonl"   # a recording any name: here one an output sink would take (the tester's)
    shutil.copy(walk, rec)
    before = rec.read_bytes()
    url = form.format(abs=rec)
    for option in ("-o", "--summary-json", "--plot"):
        target = rec if option == "-o" else rec.with_suffix(".json" if option == "--summary-json" else ".png")
        if target != rec:  # the same recording under the output's own suffix, through a link
            target.symlink_to(rec)
        assert main(["run", str(cfg), "--input", url, option, str(target), "--force", "-q"]) == 2
        assert "is an input of this run" in capsys.readouterr().err
        assert rec.read_bytes() == before
    assert main(["run", str(cfg), "--input", url, "-q", "-o", str(tmp / "fine.csv")]) == 0


class _CaptureSource(Source):
    """A third party's source reading a local file through its own scheme (``capt://PATH``)."""

    name = "capture_for_tests"
    schemes = ("capt",)

    class Params(Params):
        path: str

    @classmethod
    def from_url(cls, url: str, **options):
        return cls(cls.Params(path=url.split("://", 1)[1]))

    def input_paths(self):
        return (self.params.path,)

    def lines(self):
        with open(self.params.path, encoding="utf-8") as fh:
            yield from fh


class _CapturePlugin:
    from fusion import hookimpl

    @hookimpl
    def fusion_register_components(self, registry):
        registry.add(_CaptureSource)


def test_a_plugin_sources_input_paths_are_never_outputs(work, monkeypatch, capsys):
    import fusion.registry

    tmp, cfg, rec = work
    monkeypatch.setattr(fusion.registry, "_DEFAULT", fusion.registry.make_plugin_manager([_CapturePlugin()])[1])
    before = rec.read_bytes()
    link = tmp / "link.csv"
    link.symlink_to(rec)
    assert main(["run", str(cfg), "--input", f"capt://{rec}", "-o", str(link), "--force", "-q"]) == 2
    assert "is an input of this run" in capsys.readouterr().err and rec.read_bytes() == before
    out = tmp / "ok.csv"
    assert main(["run", str(cfg), "--input", f"capt://{rec}", "-o", str(out), "-q"]) == 0
    assert out.read_text().startswith("t,px,py")


def test_source_input_paths_default_to_none_and_the_recording_names_its_file(tmp_path):
    from fusion.sources.recording import RecordingSource

    class Udp(Source):
        class Params(Params):
            url: str

    assert Udp.from_url("udp://1.2.3.4:5").input_paths() == ()
    assert RecordingSource.from_url("-").input_paths() == ()
    assert RecordingSource.from_url(f"file://{tmp_path}/a.log").input_paths() == (f"{tmp_path}/a.log",)
    assert RecordingSource.from_url(f"file://localhost{tmp_path}/a.log").input_paths() == (f"{tmp_path}/a.log",)
    assert RecordingSource.from_url("b.log").input_paths() == ("b.log",)


def test_tui_record_is_checked_as_an_output_before_the_view_starts(work, capsys):
    tmp, cfg, rec = work
    assert main(["tui", str(cfg), "--port", "loop://", "--record", str(tmp / "nofolder" / "raw.log")]) == 2
    assert "--record" in (err := capsys.readouterr().err) and "does not exist" in err
    assert main(["tui", str(cfg), "--port", "loop://", "--record", str(cfg)]) == 2
    assert "--record" in capsys.readouterr().err and cfg.read_text().startswith(CONFIG.read_text()[:20])


# --------------------------------------------------------------------------- 4. an empty --input
@pytest.mark.parametrize("argv", [
    ["run", "{cfg}", "--input", "", "-q", "--summary-json", "{tmp}/s.json"],
    ["run", "{cfg}", "-q", "-o", ""],
    ["run", "{cfg}", "-q", "--summary-json", ""],
    ["tui", "{cfg}", "--input", ""],
    ["tui", "{cfg}", "--port", ""],
    ["tui", "{cfg}", "--port", "loop://", "--record", ""],
])
def test_an_empty_input_or_output_is_exit_2_never_the_configs_own_recording(work, argv, capsys):
    tmp, cfg, rec = work
    argv = [a.format(cfg=cfg, tmp=tmp) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "'': empty" in err and len(err.strip().splitlines()) == 1
    assert not (tmp / "s.json").exists()
