"""initial.from_sensor only from a sensor whose model gives a position (fusion.initial_checks): a range
sensor is a validate error (exit 2) naming the sensor and its model; the shipped configs' fix sensors pass."""
from __future__ import annotations

import numpy as np
import pytest
from world_helpers import ROOT, edited

from fusion.api import StateLayout
from fusion.cli import main
from fusion.initial_checks import selects_position


def test_a_range_sensor_cannot_start_the_position(tmp_path, capsys):
    uwb = ROOT / "configs" / "uwb_pv_ukf.yaml"
    cfg = edited(uwb, tmp_path / "c.yaml", recording=str(ROOT / "recordings" / "uwb_route1.log"),
                 **{"initial.from_sensor": "uwb"})
    assert main(["validate", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert "initial.from_sensor" in err and "sensor 'uwb' (model 'range')" in err and "c.yaml:" in err
    assert main(["run", str(cfg), "-q", "--no-progress"]) == 2


@pytest.mark.parametrize("config", ["imu_gps_mag_ekf.yaml", "abps_ins.yaml", "px4_ins_gps_mag.yaml"])
def test_fix_sensors_pass(config):
    assert main(["validate", str(ROOT / "configs" / config)]) == 0


class _Model:
    def __init__(self, h):
        self.h = h


def test_selects_position_on_h():
    lay = StateLayout.parse("v:2 p:2")
    x0 = np.array([0.1, 0.2, 3.0, 4.0])
    p = lay["p"]
    assert selects_position(_Model(lambda x: np.asarray(x)[..., 2:4]), x0, p)                 # z = p
    assert selects_position(_Model(lambda x: np.r_[np.asarray(x)[2:4], x[0]]), x0, p)         # z = [p, v_x]
    assert not selects_position(_Model(lambda x: np.asarray(x)[..., :2]), x0, p)              # z = v
    assert not selects_position(_Model(lambda x: np.atleast_1d(np.hypot(x[2], x[3]))), x0, p)  # a range
    assert not selects_position(_Model(lambda x: 2.0 * np.asarray(x)[..., 2:4]), x0, p)       # scaled
    def needs_message(x):
        raise RuntimeError("bound to a beacon by observe()")
    assert not selects_position(_Model(needs_message), x0, p)
