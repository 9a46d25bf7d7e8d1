"""Hostile config values and command lines (issue 28 items 3-4): each ends with one exit-2 line (or an
ok with a note) instead of a hang, an internal error (exit 1), or a destroyed input."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fusion.cli import main

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"
RECORDING = ROOT / "recordings" / "example_2d.log"


def config_with(tmp_path: Path, recording: str, name: str = "c.yaml") -> Path:
    """example_2d.yaml with its ``recording:`` replaced (a YAML double-quoted string: escapes allowed)."""
    text = CONFIG.read_text().replace("recording: ../recordings/example_2d.log", f'recording: "{recording}"')
    assert f'recording: "{recording}"' in text
    cfg = tmp_path / name
    cfg.write_text(text)
    return cfg


def one_error_line(capsys, cfg: Path) -> str:
    err = capsys.readouterr().err.removeprefix("fusion run: error: ")
    assert err.startswith(str(cfg)) and len(err.strip().splitlines()) == 1 and "internal error" not in err, err
    return err


def validate_in_subprocess(cfg: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    """``fusion validate`` in a child: a hang ends as TimeoutExpired (a generous bound, not a timing test)."""
    return subprocess.run([sys.executable, "-m", "fusion.cli", "validate", str(cfg)], capture_output=True,
                          text=True, timeout=timeout, stdin=subprocess.DEVNULL)


def test_validate_does_not_read_a_fifo_recording(tmp_path):
    fifo = tmp_path / "stream.log"
    os.mkfifo(fifo)
    done = validate_in_subprocess(config_with(tmp_path, str(fifo)))   # waited for a writer forever
    assert done.returncode == 0, done.stderr
    assert "is a FIFO (named pipe): not read" in done.stderr and ": ok:" in done.stdout


def test_validate_does_not_read_a_terminal_recording(tmp_path):
    master, slave = os.openpty()
    try:
        done = validate_in_subprocess(config_with(tmp_path, os.ttyname(slave)))   # waited for a line forever
    finally:
        os.close(master)
        os.close(slave)
    assert done.returncode == 0, done.stderr
    assert "is a character device (a terminal or serial port): not read" in done.stderr


@pytest.mark.parametrize("make, said", [
    (lambda d: "/tmp/" + "a" * 5000, "a path of 5005 bytes, longer than the system's 4096"),
    (lambda d: "/tmp/" + "a" * 300 + "/x.log", "a path component of 300 bytes"),
    (lambda d: "/tmp/rec\\0.log", "a path cannot hold a NUL byte"),
])
@pytest.mark.parametrize("command", ["validate", "run"])
def test_a_path_the_system_refuses_is_one_config_line(tmp_path, capsys, make, said, command):
    cfg = config_with(tmp_path, make(tmp_path))
    assert main([command, str(cfg), *(["-q"] if command == "run" else [])]) == 2   # not 1 (OSError, ValueError)
    err = capsys.readouterr().err
    assert f"{cfg}:5: recording:" in err and said in err and len(err.strip().splitlines()) == 1, err


def test_a_symlink_loop_recording_is_one_config_line(tmp_path, capsys):
    (tmp_path / "a.log").symlink_to(tmp_path / "b.log")
    (tmp_path / "b.log").symlink_to(tmp_path / "a.log")
    cfg = config_with(tmp_path, str(tmp_path / "a.log"))
    assert main(["validate", str(cfg)]) == 2   # not 1: RuntimeError: Symlink loop
    assert "Too many levels of symbolic links" in one_error_line(capsys, cfg)
    assert main(["run", str(cfg), "-q"]) == 2
    assert "internal error" not in capsys.readouterr().err


@pytest.mark.skipif(not Path("/proc/self/mem").exists(), reason="no /proc")
def test_an_unreadable_recording_is_one_config_line(tmp_path, capsys):
    cfg = config_with(tmp_path, "/proc/self/mem")
    assert main(["validate", str(cfg)]) == 2   # not 1: OSError: Input/output error
    assert "cannot read /proc/" in one_error_line(capsys, cfg)


def test_a_large_yaml_of_numbers_is_refused_by_its_size(tmp_path, capsys):
    big = tmp_path / "numbers.yaml"
    big.write_text("\n".join(f"- {i}.5" for i in range(120_000)))   # ~1 MB: parsed for seconds before
    assert main(["validate", str(big)]) == 2
    err = one_error_line(capsys, big)
    assert f"larger than 256 KiB ({big.stat().st_size / 1024 ** 2:.3g} MiB), the most a YAML file may be" in err, err


def test_many_values_under_the_size_limit_are_refused_while_reading(capsys):
    from fusion.yamlsource import MAX_VALUES, LocatedYAML

    text = "[" + ",".join("1" for _ in range(MAX_VALUES + 5)) + "]"
    with pytest.raises(Exception) as info:
        LocatedYAML.from_text(text, "t.yaml")
    assert f"holds more than {MAX_VALUES} values" in str(info.value)


def offset_config(tmp_path: Path, offset: float, latency: float, other: float = 0.0) -> Path:
    text = CONFIG.read_text().replace("../recordings/", f"{ROOT}/recordings/")
    text = text.replace("    role: measurement\n", f"    role: measurement\n    time_offset: {offset}\n", 1)
    text = text.replace("  max_latency: 0.05", f"  max_latency: {latency}")
    text = text.replace("sensors:\n", "sensors:\n  other:\n    model: range\n    noise: {sd: 0.1}\n"
                        f"    time_offset: {other}\n", 1)
    cfg = tmp_path / "offset.yaml"
    cfg.write_text(text)
    return cfg


def test_a_negative_offset_beyond_max_latency_is_refused(tmp_path, capsys):
    cfg = offset_config(tmp_path, -0.5, 0.2)
    for command in (["validate", str(cfg)], ["run", str(cfg), "-q"]):
        assert main(command) == 2   # not 0 with every uwb message dropped as late
        err = one_error_line(capsys, cfg)
        assert "sensors.uwb.time_offset: -0.5 s puts uwb's messages 0.5 s behind other's" in err, err
        assert "scheduler.max_latency (0.2 s)" in err and "max_latency >= 0.5" in err


@pytest.mark.parametrize("offset, latency, other", [(-0.5, 0.5, 0.0), (-0.5, 0.0, -0.5), (0.3, 0.0, 0.3),
                                                     (-0.1, 0.2, 0.05)])
def test_offsets_that_fit_in_max_latency_pass(tmp_path, capsys, offset, latency, other):
    cfg = offset_config(tmp_path, offset, latency, other)
    assert main(["validate", str(cfg)]) == 0, capsys.readouterr().err


def test_a_positive_offset_puts_the_other_sensor_behind(tmp_path, capsys):
    cfg = offset_config(tmp_path, 0.0, 0.1, other=0.4)
    assert main(["validate", str(cfg)]) == 2
    assert "sensors.uwb.time_offset: 0 s puts uwb's messages 0.4 s behind other's" in one_error_line(capsys, cfg)


@pytest.mark.parametrize("output", [["--summary-json", "/dev/fd/0"], ["-o", "/dev/stdin"], ["-o", "LINK"]])
def test_an_output_that_is_the_standard_input_file_is_refused(tmp_path, output):
    log = tmp_path / "in.log"
    log.write_bytes(RECORDING.read_bytes())
    (tmp_path / "LINK").symlink_to("/dev/fd/0")
    with log.open("rb") as stdin:
        done = subprocess.run([sys.executable, "-m", "fusion.cli", "run", str(CONFIG), "--input", "-", *output,
                               "--force", "-q"], stdin=stdin, capture_output=True, text=True, cwd=tmp_path,
                              timeout=300)
    assert done.returncode == 2, done.stderr
    assert "is an input of this run (standard input (--input -))" in done.stderr
    assert log.read_bytes() == RECORDING.read_bytes()   # not replaced by the summary or the CSV


def test_an_output_hard_linked_to_the_input_is_refused(tmp_path, capsys):
    log = tmp_path / "in.log"
    log.write_bytes(RECORDING.read_bytes())
    os.link(log, tmp_path / "out.csv")
    assert main(["run", str(CONFIG), "--input", str(log), "-o", str(tmp_path / "out.csv"), "--force", "-q"]) == 2
    assert "is an input of this run" in capsys.readouterr().err
    assert log.read_bytes() == RECORDING.read_bytes()


def test_quiet_hides_the_table_but_not_the_warnings(tmp_path, capsys):
    lines = RECORDING.read_text().splitlines()
    half = [line.replace(",uwb,", ",uwbx,") if i % 2 else line for i, line in enumerate(lines)]
    log = tmp_path / "half.log"
    log.write_text("\n".join(half) + "\n")
    main(["run", str(CONFIG), "--input", str(log), "-q"])
    out, err = capsys.readouterr()
    assert out == ""
    assert "sensor 'uwbx' is not in the config; its messages are ignored" in err   # not hidden by -q


@pytest.mark.parametrize("make, said", [(lambda d: "/tmp/" + "a" * 5000, "File name too long"),
                                        (lambda d: str(d / "a.log"), "Too many levels of symbolic links")])
def test_an_input_path_the_system_refuses_is_one_line(tmp_path, capsys, make, said):
    (tmp_path / "a.log").symlink_to(tmp_path / "b.log")
    (tmp_path / "b.log").symlink_to(tmp_path / "a.log")
    assert main(["run", str(CONFIG), "--input", make(tmp_path), "-q"]) == 2   # not 1 (OSError) for the long one
    err = capsys.readouterr().err
    assert "cannot open the recording: " + said in err and len(err.strip().splitlines()) == 1, err
