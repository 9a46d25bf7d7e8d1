"""A device, a FIFO or a huge file given as a config, scenario, mapping or sweep results file: one exit-2
line naming it, never a read that fills the memory (/dev/zero) or waits forever (a FIFO); a sweep's results
file on a full disk: one line, exit 2, and nothing left that was not there."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from fusion.testing.faults import FullAfter

from fusion.cli import main

ROOT = Path(__file__).resolve().parents[2]
CONFIG = str(ROOT / "configs" / "uwb_pv_ukf.yaml")
SCENARIO = str(ROOT / "scenarios" / "example_2d.yaml")
needs_zero = pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="no /dev/zero")


@needs_zero
@pytest.mark.parametrize("argv", [["validate", "/dev/zero"], ["run", "/dev/zero", "-q"],
                                  ["simulate", "/dev/zero", "-o", "{tmp}/x.log"]])
def test_a_device_as_a_config_or_scenario_is_one_line_exit_2(argv, tmp_path, capsys):
    assert main([a.format(tmp=tmp_path) for a in argv]) == 2
    err = capsys.readouterr()
    text = (err.err + err.out).strip()
    assert "/dev/zero: a character device, not a readable regular file" in text and len(text.splitlines()) == 1


def test_a_fifo_config_is_refused_without_waiting_for_a_writer(tmp_path, capsys):
    fifo = tmp_path / "c.yaml"
    os.mkfifo(fifo)
    assert main(["run", str(fifo), "-q"]) == 2
    assert "a FIFO, not a readable regular file" in capsys.readouterr().err


def test_a_config_over_the_limit_is_refused_naming_it(tmp_path, monkeypatch, capsys):
    import fusion.yamlsource as ys

    monkeypatch.setattr(ys, "MAX_YAML_BYTES", 1000)
    big = tmp_path / "big.yaml"
    big.write_text("# padding\n" * 200)
    assert main(["run", str(big), "-q"]) == 2
    assert f"{big}: larger than" in capsys.readouterr().err
    assert ys.MAX_YAML_BYTES == 1000 and (ROOT / "configs" / "uwb_pv_ukf.yaml").stat().st_size < 10 * 1024 * 1024


@needs_zero
def test_import_map_that_is_a_device_says_so(tmp_path, capsys):
    csv = tmp_path / "d.csv"
    csv.write_text("t,x\n0,1\n")
    assert main(["import", str(csv), "--map", "/dev/zero", "-o", str(tmp_path / "o.log")]) == 2
    err = capsys.readouterr().err
    assert "/dev/zero: a device, FIFO or socket, not a readable regular file" in err and "no such" not in err
    assert main(["import", str(csv), "--map", str(tmp_path / "none.yaml"), "-o", str(tmp_path / "o.log")]) == 2
    assert "no such mapping file" in capsys.readouterr().err


@pytest.mark.parametrize("kind", ["device", "fifo"])
def test_a_sweep_results_path_that_is_no_regular_file_is_refused(kind, tmp_path, capsys):
    out = tmp_path / "r.csv"
    if kind == "device":
        if not os.path.exists("/dev/zero"):
            pytest.skip("no /dev/zero")
        out.symlink_to("/dev/zero")
    else:
        os.mkfifo(out)
    assert main(["sweep", CONFIG, "--seeds", "2", "-o", str(out), "--no-progress"]) == 2
    assert "r.csv: not a regular file" in capsys.readouterr().err


def _full_after(monkeypatch, nbytes: int):
    """The results file fails with ENOSPC once ``nbytes`` are written (a full disk, without root)."""
    import fusion.sweep.results as results

    real_open = open
    monkeypatch.setattr(results, "open", lambda *a, **k: FullAfter(real_open(*a, **k), nbytes) if "a" in a[1:2] else
                        real_open(*a, **k), raising=False)


def test_a_full_disk_under_a_new_results_file_leaves_nothing(tmp_path, monkeypatch):
    from fusion.errors import ConfigError
    from fusion.sweep.results import CsvWriter

    _full_after(monkeypatch, 5)
    out = tmp_path / "r.csv"
    with pytest.raises(ConfigError, match=r"r\.csv: cannot write the results there \(No space left on device\)$"):
        CsvWriter(out, ["key", "status", "x"])
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_a_full_disk_while_appending_keeps_the_complete_rows(tmp_path, monkeypatch):
    from fusion.errors import ConfigError
    from fusion.sweep.results import CsvWriter, read_rows

    out = tmp_path / "r.csv"
    w = CsvWriter(out, ["key", "status", "x"])
    w.write({"key": "a", "status": "ok", "x": 1.5})
    w.close()
    before = out.read_bytes()
    _full_after(monkeypatch, 12)
    w = CsvWriter(out, ["key", "status", "x"])
    w.write({"key": "b", "status": "ok", "x": 2.5})
    with pytest.raises(ConfigError, match="cannot write the results there .*; the complete rows are kept"):
        w.write({"key": "c", "status": "ok", "x": 3.5})
    w.close()
    assert out.read_bytes() == before + b"b,ok,2.5\r\n" and [r["key"] for r in read_rows(out)] == ["a", "b"]


def test_a_full_disk_from_the_sweep_command_is_exit_2(tmp_path, monkeypatch, capsys):
    _full_after(monkeypatch, 5)
    out = tmp_path / "r.csv"
    assert main(["sweep", CONFIG, "--seeds", "1", "-o", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "cannot write the results there" in err and "internal error" not in err and not out.exists()


def test_a_rewritten_parquet_keeps_its_mode_and_leaves_no_temporary(tmp_path):
    import pyarrow  # noqa: F401  (a test dependency: pyproject [test])
    import stat

    from fusion.sweep.results import write_parquet

    out = tmp_path / "r.parquet"
    write_parquet(out, [{"key": "a", "x": 1.0}], ["key", "x"])
    out.chmod(0o640)
    write_parquet(out, [{"key": "a", "x": 1.0}, {"key": "b", "x": 2.0}], ["key", "x"])
    assert stat.S_IMODE(out.stat().st_mode) == 0o640 and sorted(p.name for p in tmp_path.iterdir()) == ["r.parquet"]
