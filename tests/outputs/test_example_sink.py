"""The example package's .tsv sink (the model third parties copy) follows the output rules through
fusion.api.OutputFile: --force replaces, a link to a device is written in place, a full disk is one line
(exit 2) and leaves no cut or temporary file."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from fusion.testing.faults import full_disk_after

from fusion.cli import main


@pytest.fixture
def cfg(short_example):
    return short_example[0]


def test_output_file_is_part_of_the_api():
    import fusion.api
    from fusion.outputs import OutputFile

    assert fusion.api.OutputFile is OutputFile and "OutputFile" in fusion.api.__all__


def test_tsv_force_replaces_and_without_force_is_refused(installed_example, cfg, tmp_path, capsys):
    out = tmp_path / "track.tsv"
    out.write_text("old\n")
    assert main(["run", str(cfg), "-q", "-o", str(out)]) == 2
    assert "pass --force" in capsys.readouterr().err and out.read_text() == "old\n"
    assert main(["run", str(cfg), "-q", "-o", str(out), "--force"]) == 0
    assert out.read_text().splitlines()[0].split("\t") == ["t", "px", "py", "sd_px", "sd_py"]
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_tsv_through_a_link_to_a_device_is_written_in_place(installed_example, cfg, tmp_path):
    link = tmp_path / "null.tsv"
    link.symlink_to(os.devnull)
    assert main(["run", str(cfg), "-q", "-o", str(link)]) == 0
    assert link.is_symlink() and os.path.exists(os.devnull) and not Path(os.devnull).is_file()


def test_tsv_on_a_full_disk_is_one_line_and_leaves_nothing(installed_example, cfg, tmp_path, monkeypatch, capsys):
    if os.path.exists("/dev/full"):
        link = tmp_path / "full.tsv"
        link.symlink_to("/dev/full")
        assert main(["run", str(cfg), "-q", "-o", str(link)]) == 2
        err = capsys.readouterr().err
        assert "cannot write the track to" in err and "No space left on device" in err and "internal" not in err
    full_disk_after(monkeypatch, 40)            # the header fits, the first rows do not
    out = tmp_path / "t.tsv"
    assert main(["run", str(cfg), "-q", "-o", str(out)]) == 2
    assert "cannot write the track to" in capsys.readouterr().err
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
