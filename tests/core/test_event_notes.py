"""The first events of each kind a user should see are printed while a run goes: a wild time stamp dropped
by the clock guard names its line (it used to be only counted in the summary)."""
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
