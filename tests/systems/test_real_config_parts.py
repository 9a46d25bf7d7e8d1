"""The parts the real-vehicle configs added (issue 13 item 3), each on its own: the ``gps_fields`` decoder
(geodetic GPS lines -> local NED), the ``gps`` model's ``accuracy: receiver``, the magnetometer's
``field_source: alignment`` and the field rules' errors."""
from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest
from scipy.spatial.transform import Rotation

from fusion.api import BuildContext, MalformedMessage, Message, Observation, RejectedMessage, StateLayout
from fusion.cli import main
from fusion.importers.gps_decoder import GpsFieldsDecoder
from fusion_plugins.measurement.gps import Gps, GpsParams
from fusion_plugins.measurement.magnetometer import Magnetometer, MagnetometerParams, earth_field

LAYOUT = StateLayout.parse("p:3 v:3 q:4:quaternion ba:3 bw:3")
LAT, LON, ALT, GEOID = 63.4170622, 10.4082151, 66.814, 39.952


def _fix(lat, lon, alt, fix=3, nsat=12, geoid=GEOID, vn=1.0, ve=-2.0, hacc=1.5, vacc=3.0, t=1.0):
    return Message(t, "gps", (lat, lon, alt, vn, ve, 0.3, hacc, vacc, 0.8, fix, nsat, geoid))


def test_gps_fields_first_fix_is_the_origin_and_later_fixes_are_ned():
    dec = GpsFieldsDecoder(GpsFieldsDecoder.Params())
    first = dec.decode(_fix(LAT, LON, ALT))
    assert first.values[:3] == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)
    assert all(math.isnan(v) for v in first.values[3:5])          # the origin fix: position only
    lat, lon, h = pymap3d.ned2geodetic(30.0, -40.0, 5.0, LAT, LON, ALT + GEOID)
    out = dec.decode(_fix(lat, lon, h - GEOID, t=1.2))
    assert out.values[:3] == pytest.approx((30.0, -40.0, 5.0), abs=1e-6)
    assert out.values[3:5] == (1.0, -2.0) and out.values[10:] == (1.5, 3.0)
    assert dec.info()["origin"]["lat_deg"] == LAT
    windowed = GpsFieldsDecoder(GpsFieldsDecoder.Params(position_only_s=0.5))
    first, inside, after = (windowed.decode(_fix(LAT, LON, ALT, t=t)) for t in (1.0, 1.4, 1.6))
    assert math.isnan(inside.values[3]) and after.values[3:5] == (1.0, -2.0)


def test_gps_fields_rejects_weak_fixes_and_refuses_other_layouts():
    dec = GpsFieldsDecoder(GpsFieldsDecoder.Params())
    with pytest.raises(RejectedMessage, match="fix type 2"):
        dec.decode(_fix(LAT, LON, ALT, fix=2))
    with pytest.raises(RejectedMessage, match="satellites"):
        dec.decode(_fix(LAT, LON, ALT, nsat=4))
    assert dec.origin is None                       # a rejected fix never becomes the origin
    with pytest.raises(MalformedMessage, match="12, 11 or 9"):
        dec.decode(Message(1.0, "gps", (LAT, LON, ALT)))
    ardupilot = dec.decode(Message(1.0, "gps", (LAT, LON, ALT, 0.0, 0.0, 0.0, 0.8, 3, 12)))   # no GPA, no geoid
    assert math.isnan(ardupilot.values[10]) and dec.origin[2] == ALT


@pytest.mark.parametrize("fix", [7, 8])
def test_gps_fields_fix_types_7_and_8_are_not_measured_fixes(fix):
    # PX4's fix_type 8 is "extrapolated" (the receiver's dead reckoning): an ordinal test would pass it at
    # min_fix 3 as better than RTK (as the nmea decoder's GGA quality)
    dec = GpsFieldsDecoder(GpsFieldsDecoder.Params())
    with pytest.raises(RejectedMessage, match=f"fix type {fix} .*no measured fix"):
        dec.decode(_fix(LAT, LON, ALT, fix=fix))
    assert dec.origin is None and dec.counters["rejected"] == 1
    assert dec.decode(_fix(LAT, LON, ALT, fix=6)) is not None                   # RTK fixed passes
    listed = GpsFieldsDecoder(GpsFieldsDecoder.Params(fix_types=[3, 8]))       # a MAVLink source: 8 is PPP
    assert listed.decode(_fix(LAT, LON, ALT, fix=8)) is not None
    with pytest.raises(RejectedMessage, match=r"in \[3, 8\]"):
        listed.decode(_fix(LAT, LON, ALT, fix=4))
    with pytest.raises(ValueError, match="not both"):
        GpsFieldsDecoder.Params(min_fix=3, fix_types=[3])


def test_receiver_accuracy_with_the_configured_floors():
    ctx = BuildContext(layout=LAYOUT)
    gps = Gps(GpsParams(accuracy="receiver", horizontal_sd=0.5, vertical_sd=0.75, velocity_sd=0.3), ctx)
    z = (1.0, 2.0, 3.0, 0.1, 0.2, 0.8, np.nan, 12, 3, 1, 2.0, 0.4)
    R = gps.observe(Message(0.0, "gps", z)).R
    assert np.diag(R) == pytest.approx([4.0, 4.0, 0.75 ** 2, 0.09, 0.09])     # hacc 2 m above 0.5; vacc under 0.75
    dop = Gps(GpsParams(), ctx).observe(Message(0.0, "gps", z)).R
    assert np.diag(dop)[0] == pytest.approx((2.5 * 0.8) ** 2)                  # the default ignores hacc


def test_field_from_alignment_is_the_mean_sample_rotated_by_the_aligned_attitude():
    ctx = BuildContext(layout=LAYOUT)
    mag = Magnetometer(MagnetometerParams(align="none", field_source="alignment"), ctx)
    assert mag.m_n is None
    m_true = earth_field(4.0, 75.0, 52.0)
    q = Rotation.from_euler("ZYX", [40.0, 3.0, -2.0], degrees=True).as_quat()[[3, 0, 1, 2]]
    x0 = np.zeros(16)
    x0[6:10] = q
    rng = np.random.default_rng(1)
    C_nb = Rotation.from_quat(q[[1, 2, 3, 0]]).as_matrix().T
    obs = [Observation(0.01 * k, C_nb @ m_true + rng.normal(0, 0.3, 3), mag) for k in range(20)]
    from fusion_plugins.measurement.attitude import covariance_in_state

    P0 = np.eye(16)
    P0[6:10, 6:10] = covariance_in_state(q, np.eye(3) * np.radians(2.0) ** 2)   # a start from the reference
    x1, P1 = mag.align_state(x0, P0, np.zeros(6), obs, np.eye(3) * 0.09)
    assert np.array_equal(x1, x0) and np.array_equal(P1, P0)   # the attitude is left as it was
    assert mag.m_n == pytest.approx(m_true, abs=3 * 0.3 / math.sqrt(20) * 3)
    assert mag.h(x0) == pytest.approx(C_nb @ mag.m_n)


def test_field_from_alignment_without_samples_rejects_each_sample():
    mag = Magnetometer(MagnetometerParams(align="none", field_source="alignment"), BuildContext(layout=LAYOUT))
    mag.align_state(np.zeros(16), np.eye(16), np.zeros(6), [], None)
    with pytest.raises(RejectedMessage, match="alignment window"):
        mag.observe(Message(1.0, "mag", (1.0, 2.0, 3.0)))


@pytest.mark.parametrize("model, expect", [
    ({"type": "magnetometer", "align": "none"}, "give field_ned"),
    ({"type": "magnetometer", "align": "improved_triad", "field_source": "alignment"}, "set align: none"),
    ({"type": "magnetometer", "align": "none", "field_source": "alignment", "intensity": 50}, "give no field_ned"),
])
def test_field_rules_are_one_exit_2_line(tmp_path, capsys, model, expect):
    import yaml
    from pathlib import Path

    cfg = yaml.safe_load((Path(__file__).resolve().parents[2] / "configs" / "px4_ins_gps_mag.yaml").read_text())
    cfg["sensors"]["mag"]["model"] = model
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(cfg))
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "sensors.mag.model" in err[0] and expect in err[0]


def test_field_from_alignment_refuses_an_attitude_without_a_heading():
    """No attitude source before the magnetometer (no initial_attitude line): the aligned attitude's heading
    is the config's guess (the configs' q sd 0.5: about 57 deg); the field is not estimated from it, and every sample is
    rejected, saying why."""
    from fusion_plugins.measurement.attitude import covariance_in_state

    mag = Magnetometer(MagnetometerParams(align="none", field_source="alignment"), BuildContext(layout=LAYOUT))
    x0 = np.zeros(16)
    x0[6] = 1.0
    obs = [Observation(0.0, np.array([20.0, 0.0, 40.0]), mag)]
    for sd_deg, known in ((2.0, True), (20.0, False)):
        m = Magnetometer(MagnetometerParams(align="none", field_source="alignment"), BuildContext(layout=LAYOUT))
        P0 = np.eye(16)
        P0[6:10, 6:10] = covariance_in_state(x0[6:10], np.diag(np.radians([1.0, 1.0, sd_deg])) ** 2)
        m.align_state(x0, P0, np.zeros(6), obs, None)
        assert (m.m_n is not None) == known
    with pytest.raises(RejectedMessage, match="heading sd of 20 deg"):
        m.observe(Message(1.0, "mag", (1.0, 2.0, 3.0)))
    assert mag.m_n is None
