"""One simulated flight written in every layout the importers read (experiments/flight_layouts.py: older
and newer ArduPilot DataFlash, older and newer PX4 ULog) imports to the same sensor data on one clock: the
IMU, GPS and magnetometer samples of each layout equal the newer DataFlash's, shifted by the layout's boot
time, and the older GPS's fixes land on the IMU's clock (not at their GPS time of week)."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from import_helpers import ROOT, Recording, fusion_import

sys.path.insert(0, str(ROOT / "experiments"))


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    import flight_layouts as fl

    d = tmp_path_factory.mktemp("layouts")
    f = fl.flight()
    out = {}
    for layout in ("dataflash_new", "dataflash_old", "ulog_new", "ulog_old"):
        src = d / (layout + (".bin" if layout.startswith("dataflash") else ".ulg"))
        fl.write(layout, f, src)
        assert fusion_import(src, "-o", d / f"{layout}.log") == 0
        out[layout] = Recording(d / f"{layout}.log")
    return f, out


# the flight's t = 0 on each log's clock (s): DataFlash boot + 1 s / 11.46 s, ULog from its start
ZERO = {"dataflash_new": 1.0, "dataflash_old": 11.46, "ulog_new": 0.0, "ulog_old": 0.0}


@pytest.mark.parametrize("layout", list(ZERO))
def test_every_layout_gives_the_flight_on_one_clock(imported, layout):
    f, rec = imported
    r = rec[layout]
    import flight_layouts as fl

    lag = {"imu": 0.0, "mag": 0.0, "gps": fl.GPS_LAG[layout.split("_")[0]]}   # the receiver's lag
    for sensor in ("imu", "gps", "mag"):
        np.testing.assert_allclose(r.times(sensor) - ZERO[layout] - lag[sensor], f[sensor][:, 0], atol=1e-6)
    np.testing.assert_allclose(r.values("imu"), f["imu"][:, 1:], rtol=1e-6, atol=1e-6)     # float32 in the logs
    np.testing.assert_allclose(r.column("gps", "lat"), f["gps"][:, 1], atol=1e-7)
    mag_atol = 0.05 if layout.startswith("dataflash") else 1e-4    # DataFlash: whole mGauss (0.1 uT)
    np.testing.assert_allclose(r.values("mag"), f["mag"][:, 1:], atol=mag_atol)
    said = [c for c in r.comments if c.startswith("# message ")]
    assert any(c.endswith(": ARMED") for c in said) and any(c.endswith(": DISARMED") for c in said)
