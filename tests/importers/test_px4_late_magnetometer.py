"""The PX4 config on a log whose magnetometer starts after the 0.2 s alignment window (a late or slow
magnetometer, a log cut with --start): every magnetometer sample is rejected with the reason and the run
goes on with the GPS, as docs/import.md says, ending degraded (exit 4: a sensor unused) unless allowed (tester2 #14: before, the first magnetometer update aborted the
run with exit 2, no summary, and a message that align_s must be > 0)."""
from __future__ import annotations

import json

from fusion.cli import main

from import_helpers import ROOT, fusion_import, need_px4_log


def test_no_magnetometer_in_the_window_rejects_it_and_the_run_goes_on(tmp_path, capsys):
    log = need_px4_log()
    full = tmp_path / "px4.log"
    assert fusion_import(str(log), "-o", str(full)) == 0
    late = tmp_path / "late.log"
    late.write_text("".join(ln for ln in full.read_text().splitlines(keepends=True)
                            if ln.startswith("#") or not (",mag," in ln and float(ln.split(",", 1)[0]) < 0.5)))
    out = tmp_path / "s.json"
    capsys.readouterr()
    # every magnetometer sample unused is a degraded run (exit 4, the sensor named), unless allowed
    assert main(["run", str(ROOT / "configs" / "px4_ins_gps_mag.yaml"), "--input", str(late), "-q"]) == 4
    assert "mag:" in capsys.readouterr().err
    assert main(["run", str(ROOT / "configs" / "px4_ins_gps_mag.yaml"), "--input", str(late), "-q",
                 "--allow-degraded", "--summary-json", str(out)]) == 0
    s = json.loads(out.read_text())
    assert s["sensors"]["mag"]["received"] > 200 and s["sensors"]["mag"]["rejected"] == s["sensors"]["mag"]["received"]
    assert s["agreement"]["samples"] > 20
    full_run = tmp_path / "f.json"
    assert main(["run", str(ROOT / "configs" / "px4_ins_gps_mag.yaml"), "--input", str(full), "-q",
                 "--summary-json", str(full_run)]) == 0
    assert json.loads(full_run.read_text())["sensors"]["mag"]["used"] > 200     # the window had samples
