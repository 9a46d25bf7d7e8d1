"""``# fields`` lines against what a sensor's components read: the same names in another order
would be read by position, the columns silently swapped (position RMSE 0.05 -> 2.5 m, attitude 78 deg on
the ABPS recording), so the run refuses the stream at that line (exit 2); other names get a warning and are
read by position; the names the components read pass silently."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from fusion.cli import main

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "abps_ins.yaml"


def _log(tmp_path, old, new, n=6000):
    lines = (ROOT / "recordings" / "abps_mine.log").read_text().splitlines()[:n]
    assert old in lines
    path = tmp_path / "x.log"
    path.write_text("\n".join(new if ln == old else ln for ln in lines) + "\n")
    return path


@pytest.mark.parametrize("old,new,who", [
    ("# fields imu ax ay az gx gy gz", "# fields imu ay ax az gy gx gz", "process 'ins'"),
    ("# fields imu ax ay az gx gy gz", "# fields imu gx gy gz ax ay az", "process 'ins'"),
    ("# fields abps beacon range", "# fields abps range beacon", "solver 'ols_trilateration'"),
])
def test_the_same_names_in_another_order_are_refused(tmp_path, capsys, old, new, who):
    log = _log(tmp_path, old, new)
    assert main(["run", str(CONFIG), "--input", str(log), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(log) in err[0] and new in err[0] and who in err[0] and "another order" in err[0]


def test_other_names_are_warned_about_and_read_by_position(tmp_path, capsys):
    renamed = _log(tmp_path, "# fields imu ax ay az gx gy gz", "# fields imu acc_x acc_y acc_z gyr_x gyr_y gyr_z")
    same = tmp_path / "same.log"
    same.write_text("\n".join((ROOT / "recordings" / "abps_mine.log").read_text().splitlines()[:6000]) + "\n")
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert main(["run", str(CONFIG), "--input", str(renamed), "--summary-json", str(a), "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "process 'ins' reads ax ay az gx gy gz; the values are read in that order, by position" in err
    assert main(["run", str(CONFIG), "--input", str(same), "--summary-json", str(b), "--no-progress"]) == 0
    assert "by position" not in capsys.readouterr().err
    ja, jb = json.loads(a.read_text()), json.loads(b.read_text())
    assert ja["errors"] == jb["errors"]
