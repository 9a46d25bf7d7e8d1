"""One config for both GPS imports: ``fusion import --gps nmea`` writes a fix as a GGA and an RMC line,
which the real-vehicle configs' ``gps_fields`` decoder reads as it reads the geodetic fields. The synthetic
ArduPilot flight (tests/systems/ardupilot_synth.py) imported both ways and run through
configs/ardupilot_ins_gps_mag.yaml: every fix used both ways, and the agreement with the onboard estimator
within what the NMEA route loses (the vertical velocity is not in GGA/RMC; the receiver's accuracies
travel in a GST sentence)."""
from __future__ import annotations

import json
import sys

from import_helpers import ROOT, fusion_import
from fusion.cli import main

sys.path.insert(0, str(ROOT / "tests" / "systems"))


def test_fields_and_nmea_imports_run_through_one_config(tmp_path):
    from ardupilot_synth import write_bin

    write_bin(tmp_path / "f.bin")
    out = {}
    for how in ("fields", "nmea"):
        log = tmp_path / f"{how}.log"
        assert fusion_import(tmp_path / "f.bin", "-o", log, "--gps", how) == 0
        js = tmp_path / f"{how}.json"
        assert main(["run", str(ROOT / "configs" / "ardupilot_ins_gps_mag.yaml"), "--input", str(log), "-q",
                     "--summary-json", str(js)]) == 0
        out[how] = json.loads(js.read_text())
    gps_f, gps_n = out["fields"]["sensors"]["gps"], out["nmea"]["sensors"]["gps"]
    assert gps_n["malformed"] == 0 and gps_f["used"] > 100
    assert out["nmea"]["info"]["gps"]["decoder"]["fixes"] == out["fields"]["info"]["gps"]["decoder"]["fixes"]
    assert gps_n["absorbed"] == gps_n["received"] * 2 // 3              # the GGA and GST lines of each fix
    assert gps_n["used"] >= gps_f["used"] - 2                            # a gate may refuse another fix or two
    a_f, a_n = out["fields"]["agreement"], out["nmea"]["agreement"]
    assert a_n["position_rmse_m"] < a_f["position_rmse_m"] + 0.5
    assert a_n["attitude_rmse_deg"] < 2.0
