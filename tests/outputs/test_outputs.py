"""Outputs never destroy the user's data (issue 10 item 4): inputs, existing files, duplicates, devices,
FIFOs, symlinks, full disks; the plot format follows the suffix."""
from __future__ import annotations

import json
import os
import shutil
import threading
from pathlib import Path

import pytest

from fusion.cli import main

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"
SCENARIO = ROOT / "scenarios" / "example_2d.yaml"


@pytest.fixture
def work(tmp_path):
    """A config and its recording copied to a temporary folder (so nothing shipped can be harmed)."""
    rec = tmp_path / "walk.log"
    shutil.copy(ROOT / "recordings" / "example_2d.log", rec)
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(CONFIG.read_text().replace("../recordings/example_2d.log", "walk.log"))
    return tmp_path, cfg, rec


@pytest.mark.parametrize("option", ["--output", "--summary-json", "--plot"])
def test_an_output_on_an_input_is_refused_and_the_input_is_intact(work, option, capsys):
    tmp, cfg, rec = work
    for target in (rec, cfg):
        before = target.read_bytes()
        assert main(["run", str(cfg), "-q", option, str(target), "--force"]) == 2
        assert "is an input of this run" in capsys.readouterr().err
        assert target.read_bytes() == before


def test_an_existing_file_needs_force_and_the_same_file_twice_is_refused(work, capsys):
    tmp, cfg, rec = work
    out = tmp / "e.csv"
    out.write_text("keep me\n")
    assert main(["run", str(cfg), "-q", "-o", str(out)]) == 2
    assert "--force" in capsys.readouterr().err and out.read_text() == "keep me\n"
    assert main(["run", str(cfg), "-q", "-o", str(out), "--force"]) == 0
    assert out.read_text().startswith("t,px,py")
    dup = tmp / "s.json"
    assert main(["run", str(cfg), "-q", "--summary-json", str(dup), "--plot", str(tmp / "s.json")]) == 2
    assert "the same file as --summary-json" in capsys.readouterr().err and not dup.exists()


def test_simulate_never_overwrites_its_scenario(tmp_path, capsys):
    sc = tmp_path / "s.yaml"
    shutil.copy(SCENARIO, sc)
    before = sc.read_bytes()
    assert main(["simulate", str(sc), "-o", str(sc), "--force"]) == 2
    assert "is an input" in capsys.readouterr().err and sc.read_bytes() == before


def test_a_device_is_written_in_place_never_replaced(work):
    tmp, cfg, rec = work
    assert main(["run", str(cfg), "-q", "--summary-json", "/dev/null", "-o", "/dev/null", "--force"]) == 0
    st = os.stat("/dev/null")
    assert os.path.exists("/dev/null") and (st.st_mode & 0o170000) == 0o020000  # still a character device


def test_a_full_disk_is_one_line_exit_2(work, capsys):
    tmp, cfg, rec = work
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full on this system")
    assert main(["run", str(cfg), "-q", "--summary-json", "/dev/full"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot write summary to /dev/full" in err[0]


def test_a_fifo_is_streamed_into(work):
    tmp, cfg, rec = work
    fifo = tmp / "pipe"
    os.mkfifo(fifo)
    got: list[str] = []
    reader = threading.Thread(target=lambda: got.append(open(fifo).read()), daemon=True)
    reader.start()
    assert main(["run", str(cfg), "-q", "-o", str(fifo)]) == 0  # existing FIFO: no --force needed
    reader.join(10)
    assert got and got[0].startswith("t,px,py") and len(got[0].splitlines()) > 2000
    assert fifo.is_fifo()


def test_a_symlink_keeps_pointing_at_its_target(work):
    tmp, cfg, rec = work
    target = tmp / "real.json"
    target.write_text("{}")
    link = tmp / "link.json"
    link.symlink_to(target)
    assert main(["run", str(cfg), "-q", "--summary-json", str(link), "--force"]) == 0
    assert link.is_symlink() and json.loads(target.read_text())["filter"] == "ukf"


@pytest.mark.parametrize("suffix", [".pdf", ".svg", ".png"])
def test_plot_format_follows_the_suffix(work, suffix):
    tmp, cfg, rec = work
    out = tmp / f"run{suffix}"
    assert main(["run", str(cfg), "-q", "--plot", str(out)]) == 0
    magic = {".pdf": b"%PDF", ".svg": b"<?xml", ".png": b"\x89PNG"}[suffix]
    assert out.read_bytes().startswith(magic)


def test_unknown_plot_suffix_is_refused_before_the_run(work, capsys):
    tmp, cfg, rec = work
    assert main(["run", str(cfg), "-q", "--plot", str(tmp / "run.bmpx")]) == 2
    assert "unknown image suffix .bmpx" in capsys.readouterr().err
    assert not list(tmp.glob(".*tmp"))
