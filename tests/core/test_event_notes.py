"""The first events of each kind a user should see are printed while a run goes: a wild time stamp dropped
by the clock guard names its line (not only counted in the summary)."""
from __future__ import annotations

from pathlib import Path

from fusion.cli import main

ROOT = Path(__file__).resolve().parents[2]


def test_a_dropped_wild_stamp_is_printed_with_its_line(tmp_path, capsys):
    lines = (ROOT / "recordings" / "abps_mine.log").read_text().splitlines()[:3000]
    i = [k for k, ln in enumerate(lines) if ",imu," in ln][1000]
    parts = lines[i].split(",")
    parts[0] = "1e9"
    lines[i] = ",".join(parts)
    log = tmp_path / "wild.log"
    log.write_text("\n".join(lines) + "\n")
    assert main(["run", str(ROOT / "configs" / "abps_ins.yaml"), "--input", str(log)]) == 0
    err = capsys.readouterr()
    printed = err.err + err.out
    assert f"time: imu: line {i + 1}: stamp 1000000000.0 s is far from the stream's time" in printed


def test_an_endless_device_as_input_is_refused_not_read_to_its_end(tmp_path):
    """--input /dev/zero: the progress bar's duration hint must not read the 'file' to its end (it has none:
    the memory filled); the recording check then refuses it as binary, exit 2. In a subprocess with a
    timeout, so a regression fails instead of filling the machine."""
    import os
    import subprocess
    import sys

    if not os.path.exists("/dev/zero"):
        import pytest
        pytest.skip("no /dev/zero")
    r = subprocess.run([sys.executable, "-m", "fusion.cli", "run", str(ROOT / "configs" / "example_2d.yaml"),
                        "--input", "/dev/zero"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "binary data, not a text log" in r.stderr


def test_an_integer_over_pythons_digit_limit_is_a_located_config_error(tmp_path, capsys):
    """A 5000-digit number in a config (or a --filter-param value) is more digits than Python converts
    (4300): one located 'invalid YAML' line and exit 2, not an internal error."""
    text = (ROOT / "configs" / "example_2d.yaml").read_text().replace("../recordings", str(ROOT / "recordings"))
    lines = text.splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.strip().startswith("spectral_density:"))
    lines[i] = lines[i].split(":")[0] + ": " + "1" * 5000
    cfg = tmp_path / "big.yaml"
    cfg.write_text("\n".join(lines) + "\n")
    assert main(["validate", str(cfg)]) == 2
    assert f"big.yaml:{i + 1}: invalid YAML: a value cannot be read" in capsys.readouterr().err
    assert main(["run", str(ROOT / "configs" / "example_2d.yaml"), "-q", "--filter-param", "alpha=" + "1" * 5000]) == 2
    assert "--filter-param" in capsys.readouterr().err


def test_a_scenario_too_large_to_simulate_is_refused_naming_the_field(tmp_path, capsys):
    """rate_hz 1e9 (or a duration of 1e12 s) would allocate hundreds of GB: one located line, exit 2."""
    import re

    text = (ROOT / "scenarios" / "example_2d.yaml").read_text()
    sc = tmp_path / "fast.yaml"
    sc.write_text(re.sub(r"rate_hz: *[0-9.e]+", "rate_hz: 1e9", text, count=1))
    assert main(["simulate", str(sc), "-o", str(tmp_path / "x.log")]) == 2
    err = capsys.readouterr().err
    assert "rate_hz: 1e+09 Hz" in err and "at most 5e+07" in err and not (tmp_path / "x.log").exists()


def test_a_folder_as_config_or_scenario_is_one_line_exit_2(tmp_path, capsys):
    """One line naming the folder, exit 2 (not 'internal error: IsADirectoryError: ...', exit 1)."""
    folder = tmp_path / "d.yaml"
    folder.mkdir()
    for argv in (["run", str(folder)], ["validate", str(folder)], ["simulate", str(folder), "-o", str(tmp_path / "s.log")],
                 ["sweep", str(folder), "--seeds", "2", "-o", str(tmp_path / "sw.csv")]):
        assert main(argv) == 2, argv
        printed = capsys.readouterr()
        text = printed.err + printed.out
        assert f"{folder}: is a folder, not a YAML" in text and "internal error" not in text, argv
