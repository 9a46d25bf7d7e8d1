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

from fusion.testing.faults import full_disk_after

from fusion.api import Params, Source
from fusion.cli import main

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"


@pytest.fixture
def work(tmp_path, short_example):
    """(folder, config, recording): a config with a short recording of its own, in a temporary folder."""
    return (tmp_path, *short_example)


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


# --------------------------------------------------------------------------- 2. write errors, full disks
def _enospc_after(monkeypatch, nbytes: int):
    """Every temporary output file (fusion.outputs) fails with ENOSPC once ``nbytes`` are written: a full
    disk without root (a real tmpfs of 64k behaves the same)."""
    full_disk_after(monkeypatch, nbytes)


def test_a_full_device_is_one_line_exit_2_after_the_summary(work, capsys):
    tmp, cfg, rec = work
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full")
    summary = tmp / "s.json"
    assert main(["run", str(cfg), "-o", "/dev/full", "--summary-json", str(summary)]) == 2
    cap = capsys.readouterr()
    assert cap.err.strip().splitlines()[-1] == \
        "fusion run: error: cannot write estimates to /dev/full: No space left on device"
    assert "internal error" not in cap.err and "Errors against truth" in cap.out  # the summary is kept
    assert summary.exists()


def test_a_full_disk_leaves_no_cut_file_and_no_temporary(work, monkeypatch, capsys):
    tmp, cfg, rec = work
    _enospc_after(monkeypatch, 20_000)
    out = tmp / "out.csv"
    assert main(["run", str(cfg), "-q", "-o", str(out), "--summary-json", str(tmp / "s.json")]) == 2
    assert "cannot write estimates to" in capsys.readouterr().err
    assert not out.exists() and _leftovers(tmp) == []
    old = tmp / "old.csv"
    old.write_text("a good file\n")
    assert main(["run", str(cfg), "-q", "-o", str(old), "--force"]) == 2
    assert old.read_text() == "a good file\n" and _leftovers(tmp) == []  # --force never trades it for a cut one


def test_simulate_on_a_full_disk_keeps_the_old_recording(tmp_path, monkeypatch, capsys):
    _enospc_after(monkeypatch, 10_000)
    log = tmp_path / "sim.log"
    assert main(["simulate", str(ROOT / "scenarios" / "example_2d.yaml"), "-o", str(log)]) == 2
    assert "cannot write the recording to" in capsys.readouterr().err
    assert not log.exists() and _leftovers(tmp_path) == []
    log.write_text("# a good recording\n")
    assert main(["simulate", str(ROOT / "scenarios" / "example_2d.yaml"), "-o", str(log), "--force"]) == 2
    assert log.read_text() == "# a good recording\n" and _leftovers(tmp_path) == []


def test_output_file_discards_on_an_exception_and_on_a_failed_close(tmp_path, monkeypatch):
    from fusion.errors import FusionError
    from fusion.outputs import OutputFile, write_text

    target = tmp_path / "t.txt"
    with pytest.raises(RuntimeError):
        with OutputFile(target) as out:
            out.write("half")
            raise RuntimeError("the writer failed")
    assert not target.exists() and _leftovers(tmp_path) == []
    _enospc_after(monkeypatch, 3)
    with pytest.raises(FusionError, match=r"cannot write summary to .*t\.txt: No space left on device"):
        write_text(target, "more than three bytes", what="summary")
    assert not target.exists() and _leftovers(tmp_path) == []


# --------------------------------------------------------------------------- 7. permission bits
def test_force_keeps_the_replaced_files_permission_bits(work):
    tmp, cfg, rec = work
    out, summary = tmp / "ro.csv", tmp / "ro.json"
    for p, mode in ((out, 0o444), (summary, 0o640)):
        p.write_text("old\n")
        p.chmod(mode)
    assert main(["run", str(cfg), "-q", "-o", str(out), "--summary-json", str(summary), "--force"]) == 0
    assert out.read_text().startswith("t,px") and stat.S_IMODE(out.stat().st_mode) == 0o444
    assert stat.S_IMODE(summary.stat().st_mode) == 0o640
    new = tmp / "new.csv"
    assert main(["run", str(cfg), "-q", "-o", str(new)]) == 0
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(new.stat().st_mode) == 0o666 & ~umask


# --------------------------------------------------------------------------- 3. stdout: -o -, closed pipes
def _fusion(*argv: str, head: int | None = None) -> tuple[int, bytes, bytes]:
    """Run the fusion CLI in a subprocess; with ``head``, its stdout goes through ``head -n HEAD``."""
    cmd = [sys.executable, "-m", "fusion.cli", *argv]
    if head is None:
        p = subprocess.run(cmd, capture_output=True, timeout=120)
        return p.returncode, p.stdout, p.stderr
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    h = subprocess.run(["head", "-n", str(head)], stdin=proc.stdout, capture_output=True, timeout=120)
    proc.stdout.close()
    err = proc.stderr.read()
    return proc.wait(60), h.stdout, err


def test_dash_output_is_only_csv_and_the_summary_goes_to_stderr(work):
    tmp, cfg, rec = work
    code, out, err = _fusion("run", str(cfg), "-o", "-")
    assert code == 0
    lines = out.decode().splitlines()
    assert lines[0].startswith("t,px,py") and all(ln[0].isdigit() for ln in lines[1:])
    assert b"Errors against truth" in err


@pytest.mark.parametrize("argv, codes", [(("-o", "-", "-q"), {141}), ((), {0, 141})])
def test_a_closed_stdout_ends_quietly_with_141(work, argv, codes):
    """The CSV on stdout is far beyond a pipe's buffer: its reader's exit is always seen (141). The summary
    table alone (a few kB) may fit in the pipe before ``head`` exits: then nothing fails (0); either way no
    message and no traceback."""
    tmp, cfg, rec = work
    code, out, err = _fusion("run", str(cfg), *argv, head=2)
    assert len(out.splitlines()) == 2
    assert code in codes and err == b"", (code, err.decode())


class _PrintingSink:
    """A plugin's sink that prints to stdout itself (not through OutputFile), whose reader went away."""

    def on_estimate(self, estimate):
        raise BrokenPipeError(errno.EPIPE, "Broken pipe")

    def close(self):
        pass


@pytest.mark.parametrize("gone,code", [(True, 141), (False, 1)])
def test_a_plugins_broken_pipe_is_quiet_only_when_stdout_is_gone(work, monkeypatch, capsys, gone, code):
    import fusion.cli
    import fusion.sources.select as select

    tmp, cfg, rec = work
    monkeypatch.setattr(select, "open_sink", lambda *a, **k: _PrintingSink())
    monkeypatch.setattr(fusion.cli, "_stdout_gone", lambda: gone)
    assert main(["run", str(cfg), "-q", "-o", str(tmp / "x.csv")]) == code
    err = capsys.readouterr().err
    assert (err == "") if gone else ("internal error" in err)
