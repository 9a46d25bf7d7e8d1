"""A config value contradicting the recording's header (fusion.header_checks): `fusion validate` (with
--input too) and `fusion run` refuse with exit 2 and one line naming both values and where each came from;
`prefer: config` (per quantity or for all) lets the config's value stand."""
from __future__ import annotations

import pytest
from world_helpers import ROOT, edited, run

from fusion.cli import main

MAG = ROOT / "configs" / "imu_gps_mag_ekf.yaml"
POSE = ROOT / "configs" / "ultrasonic_3d_pose.yaml"
CAR = ROOT / "recordings" / "car_gps_mag.log"
WALK = ROOT / "recordings" / "ultrasonic_3d_walk.log"

# (config, edits, quantity, what the one line must say: the config's value, the header's place)
CASES = [
    (MAG, {"sensors.mag.model.field_ned": [20.0, 0.0, 45.0]}, "magnetic_field",
     ["sensors.mag.model: the magnetic field [20, 0, 45]", "car_gps_mag.log:21"]),
    (MAG, {"sensors.mag.model.declination_deg": 16.6, "sensors.mag.model.inclination_deg": 68.4,
           "sensors.mag.model.intensity": 53.6}, "magnetic_field", ["car_gps_mag.log:21", "deg and"]),
    (MAG, {"process.gravity": 9.78}, "gravity", ["process.gravity: 9.78 m/s^2 in the config, 9.80665",
                                                  "car_gps_mag.log:8"]),
    (MAG, {"sensors.gps.decoder.origin": {"lat_deg": -23.3, "lon_deg": -45.876, "alt_m": 600.0}}, "origin",
     ["sensors.gps.decoder.origin: (-23.3000000", "car_gps_mag.log:9", "m apart"]),
    (POSE, {"beacons.B4": [0.0, 0.0, 2.5]}, "beacons", ["beacons.B4: [0, 0, 2.5] in the config, [0, 0, 2.6]",
                                                        "ultrasonic_3d_walk.log:12"]),
    (POSE, {"sensors.us.model.receivers": [[0, 0, 1], [0, 1, 0], [1, 0, 0], [0, 0, -1]]}, "receivers",
     ["4 receivers in the config, 32 in the recording", "ultrasonic_3d_walk.log:17"]),
]


@pytest.mark.parametrize("config, edits, quantity, says", CASES, ids=[f"{c[2]}{i}" for i, c in enumerate(CASES)])
def test_validate_refuses_a_contradiction_unless_preferred(config, edits, quantity, says, tmp_path, capsys):
    rec = CAR if config == MAG else WALK
    cfg = edited(config, tmp_path / "c.yaml", recording=str(rec), **edits)
    assert main(["validate", str(cfg)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"prefer: {{{quantity}: config}}" in err
    for text in says:
        assert text in err
    assert main(["validate", str(edited(cfg, tmp_path / "p.yaml", prefer={quantity: "config"}))]) == 0
    assert main(["validate", str(edited(cfg, tmp_path / "a.yaml", prefer="config"))]) == 0


def test_validate_input_checks_against_another_recording(tmp_path, capsys):
    # the shipped config holds against its recording; a field given by hand is checked against --input's
    cfg = edited(MAG, tmp_path / "c.yaml", recording=str(CAR),
                 **{"sensors.mag.model.field_ned": [17.807917, -6.658107, -13.812953]})
    assert main(["validate", str(cfg)]) == 0
    other = tmp_path / "seattle.log"
    other.write_text(CAR.read_text().replace("# mag earth_field_ned: 17.807917 -6.658107 -13.812953",
                                             "# mag earth_field_ned: 18.909 5.637 49.836"))
    capsys.readouterr()
    assert main(["validate", str(cfg), "--input", str(other)]) == 2
    assert "seattle.log:21" in capsys.readouterr().err


def test_run_refuses_before_any_output(tmp_path, capsys):
    cfg = edited(MAG, tmp_path / "c.yaml", recording=str(CAR), **{"sensors.mag.model.field_ned": [20.0, 0.0, 45.0]})
    code, summary = run(cfg, None, tmp_path / "s.json")
    assert code == 2 and summary is None
    assert "contradicts the recording's [17.8079, -6.65811, -13.813]" in capsys.readouterr().err


def test_what_the_config_leaves_out_the_recording_declares(tmp_path):
    from fusion.config import load_system

    text = CAR.read_text().replace("# gravity: 9.80665", "# gravity: 9.7925", 1)
    log = tmp_path / "equator.log"
    log.write_text(text)
    system = load_system(MAG, recording=log)          # the shipped config names no gravity
    assert system.process.g == 9.7925
    assert load_system(MAG).process.g == 9.80665        # its own recording's
    cfg = edited(POSE, tmp_path / "c.yaml", recording=str(WALK), beacons=None)
    system = load_system(cfg)                           # no beacons: the header's
    assert sorted(system.beacons) == ["B1", "B2", "B3", "B4"] and list(system.beacons["B4"]) == [0.0, 0.0, 2.6]
