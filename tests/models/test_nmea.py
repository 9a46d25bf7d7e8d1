"""Decoder ``nmea`` (paper 002 eqs. 5-6): real sentences, checksums, epochs, invalid fixes, NED by pymap3d."""
from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest

from fusion.api import MalformedMessage, Message, RejectedMessage
from fusion.logformat import checksum, parse_line
from fusion_plugins.decoders.nmea import KNOT, NmeaDecoder, NmeaParams

# Real receiver output: the NMEA reference examples (gpsinformation.org) and a SiRF receiver's log line.
GGA = "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47"
RMC = "$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A"
VTG = "$GPVTG,054.7,T,034.4,M,005.5,N,010.2,K*48"
GSA = "$GPGSA,A,3,04,05,,09,12,,,24,,,,,2.5,1.3,2.1*39"
GSV = "$GPGSV,3,1,11,10,63,137,17,07,61,098,15,05,59,290,20,08,54,157,30*70"
GGA2 = "$GPGGA,092750.000,5321.6802,N,00630.3372,W,1,8,1.03,61.7,M,55.2,M,,*76"
RMC2 = "$GPRMC,092750.000,A,5321.6802,N,00630.3372,W,0.02,31.66,280511,,,A*43"
ORIGIN = {"lat_deg": 48.1, "lon_deg": 11.5, "alt_m": 500.0}


def dec(**kw) -> NmeaDecoder:
    return NmeaDecoder(NmeaParams(**kw))


def msg(sentence: str, t: float = 1.0) -> Message:
    return Message(t, "gps", (sentence,), 7)


def sentence(body: str) -> str:
    return f"${body}*{checksum(body)}"


def test_registered():
    from fusion.registry import default_registry

    assert default_registry().get("decoder", "nmea") is NmeaDecoder


def test_one_epoch_gga_rmc_is_one_fix_in_ned():
    d = dec(origin=ORIGIN)
    assert d.decode(msg(GGA)) is None                       # epoch not complete yet
    out = d.decode(msg(RMC))
    assert out is not None and out.t == 1.0 and out.sensor == "gps" and out.line == 7
    pn, pe, pd, vn, ve, hdop, vdop, sats, quality, averaged = out.values
    lat, lon = 48 + 7.038 / 60, 11 + 31.0 / 60
    ref = pymap3d.geodetic2ned(lat, lon, 545.4 + 46.9, 48.1, 11.5, 500.0)   # ellipsoidal h = MSL + N
    np.testing.assert_allclose([pn, pe, pd], ref, atol=1e-6)
    speed, course = 22.4 * KNOT, math.radians(84.4)
    np.testing.assert_allclose([vn, ve], [speed * math.cos(course), speed * math.sin(course)], rtol=1e-12)
    assert (hdop, sats, quality, averaged) == (0.9, 8.0, 1.0, 1.0) and math.isnan(vdop)
    assert d.counters["epochs"] == 1


def test_gsa_gives_vdop_and_vtg_velocity_when_no_rmc():
    d = dec(origin=ORIGIN, epoch=["GGA", "VTG"])
    assert d.decode(msg(GSA)) is None
    assert d.decode(msg(GSV)) is None                        # not fused, not an error
    assert d.decode(msg(GGA)) is None
    out = d.decode(msg(VTG))
    vn, ve, hdop, vdop = out.values[3:7]
    np.testing.assert_allclose(math.hypot(vn, ve), 10.2 / 3.6, rtol=1e-12)
    np.testing.assert_allclose(math.degrees(math.atan2(ve, vn)), 54.7, rtol=1e-12)
    assert (hdop, vdop) == (1.3, 2.1)


@pytest.mark.parametrize("bad, why", [
    (GGA[:-2] + "48", "checksum"),                           # wrong checksum
    (GGA.split("*")[0], "checksum"),                          # no checksum at all
    ("$GPGGA,12351*" + checksum("GPGGA,12351")[:1], "parse"),  # truncated
    ("GPGGA,123519,4807.038,N", "not an NMEA"),
])
def test_bad_sentences_are_malformed(bad, why):
    with pytest.raises(MalformedMessage):
        dec(origin=ORIGIN).decode(msg(bad))


@pytest.mark.parametrize("lat, lon", [("9507.038", "01131.000"), ("4867.038", "01131.000"), ("4807.038", "18131.000")])
def test_position_out_of_range_is_malformed(lat, lon):
    d = dec(origin=ORIGIN, epoch=["GGA"])
    with pytest.raises(MalformedMessage, match="out of range"):
        d.decode(msg(sentence(f"GPGGA,123519,{lat},N,{lon},E,1,08,0.9,545.4,M,46.9,M,,")))


def test_lost_fix_is_rejected_once_per_epoch():
    d = dec(origin=ORIGIN)
    assert d.decode(msg(sentence("GPGGA,140140.00,,,,,0,00,99.9,,M,,M,,"))) is None
    with pytest.raises(RejectedMessage, match="quality 0"):
        d.decode(msg(sentence("GPRMC,140140.00,V,,,,,,,100608,,,N")))
    assert d.counters["invalid"] == 1
    assert d.decode(msg(GGA2, 2.0)) is None and d.decode(msg(RMC2, 2.0)) is not None   # and goes on


def test_a_vtg_sent_before_its_gga_is_of_that_epoch():
    """u-blox order (VTG, then GGA): the time-less VTG of second k belongs to GGA_k's epoch; dropping it as
    an incomplete epoch would emit every fix with the next second's VTG, 1 s late."""
    d = dec(origin=ORIGIN, epoch=["GGA", "VTG"])
    fixes = []
    for k in range(4):
        hms = f"1235{19 + k:02d}"
        vtg = sentence(f"GPVTG,{90.0:.1f},T,,M,{10.0 + k:.3f},N,{(10.0 + k) * 1.852:.3f},K,A")
        gga = sentence(f"GPGGA,{hms},4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,")
        assert d.decode(msg(vtg, float(k))) is None
        fixes.append(d.decode(msg(gga, float(k))))
    assert all(f is not None for f in fixes) and [f.t for f in fixes] == [0.0, 1.0, 2.0, 3.0]
    np.testing.assert_allclose([f.values[4] for f in fixes], [(10.0 + k) * KNOT for k in range(4)])   # east
    assert d.counters["incomplete"] == 0


def test_incomplete_epoch_dropped_and_counted():
    d = dec(origin=ORIGIN)
    assert d.decode(msg(GGA)) is None                        # RMC of 12:35:19 never comes
    assert d.decode(msg(GGA2, 2.0)) is None
    assert d.decode(msg(RMC2, 2.0)).values[0] != 0.0
    assert d.counters == {"epochs": 1, "invalid": 0, "incomplete": 1, "origin_fixes": 0}


def _fixes(lat0, lon0, h0, ned, start=0, knots=None):
    """GGA+RMC pairs of positions given in NED about (lat0, lon0, h0), as a receiver formats them; RMC speed
    ``knots[k]`` (course 90 deg, east) or 0."""
    from fusion_plugins.simulators.gps import _lat, _lon
    out = []
    for k, (n, e, d) in enumerate(ned):
        lat, lon, h = pymap3d.ned2geodetic(n, e, d, lat0, lon0, h0)
        la, ns = _lat(float(lat))
        lo, ew = _lon(float(lon))
        hms = f"1400{(start + k) % 60:02d}.00"
        out.append(sentence(f"GPGGA,{hms},{la},{ns},{lo},{ew},1,08,1.0,{float(h):.3f},M,0.0,M,,"))
        kn = 0.0 if knots is None else knots[k]
        out.append(sentence(f"GPRMC,{hms},A,{la},{ns},{lo},{ew},{kn:.3f},90.0,100608,,,A"))
    return out


def test_simulated_sentences_carry_minutes_that_round_to_sixty():
    """34.99999999999 deg was written 3459.9999999... -> '3460.0000000', which the decoder refuses; the
    minutes now carry into the degrees. Decoded back, each is the angle to the text's resolution."""
    from fusion_plugins.simulators.gps import _lat, _lon

    for deg in (34.99999999999, -35.0 + 1e-12, 34.5, 0.0, 89.999999999999):
        text, hemi = _lat(deg)
        d, m = int(text[:2]), float(text[2:])
        assert m < 60.0 and abs((d + m / 60.0) * (1 if hemi == "N" else -1) - deg) < 2e-9
    text, hemi = _lon(-179.999999999999)
    assert text == "18000.0000000" and hemi == "W"


def test_ned_round_trip_through_sentences():
    """NED -> geodetic (pymap3d) -> GGA text -> decoder -> NED: equal to the text's resolution (mm)."""
    rng = np.random.default_rng(3)
    lat0, lon0, h0 = -23.21, -45.876, 600.0
    ned = rng.uniform(-3000, 3000, (20, 3)) * [1, 1, 0.05]
    d = dec(origin={"lat_deg": lat0, "lon_deg": lon0, "alt_m": h0})
    got = []
    for k, s in enumerate(_fixes(lat0, lon0, h0, ned)):
        out = d.decode(msg(s, float(k // 2)))
        if out is not None:
            got.append(out.values[:3])
    np.testing.assert_allclose(np.array(got), ned, atol=2e-3)


def test_origin_from_static_fixes_is_their_ecef_mean():
    """Paper 002 sec. 3.1: the origin is the mean of the static fixes; one fix at the origin (NED 0, the
    count N) ends the window, later fixes are NED about it."""
    rng = np.random.default_rng(5)
    lat0, lon0, h0 = 35.0, 139.0, 40.0
    static = rng.normal(0, [2.0, 2.0, 3.0], (10, 3))
    moving = np.array([[100.0, 50.0, -2.0], [200.0, 60.0, -3.0]])
    d = dec(origin_s=9.0)
    outs = [d.decode(msg(s, float(k // 2))) for k, s in enumerate(_fixes(lat0, lon0, h0, np.vstack([static, moving])))]
    outs = [o for o in outs if o is not None]
    assert len(outs) == 3
    first = outs[0]
    assert first.t == 9.0 and first.values[9] == 10.0
    np.testing.assert_allclose(first.values[:3], 0.0, atol=1e-6)
    assert math.isnan(first.values[3])
    ecef = np.array([pymap3d.geodetic2ecef(*pymap3d.ned2geodetic(*p, lat0, lon0, h0)) for p in static]).mean(axis=0)
    o = pymap3d.ecef2geodetic(*ecef)
    np.testing.assert_allclose(d.origin, o, atol=1e-3, rtol=0)           # the text resolution: 1e-7 min, 1 mm
    np.testing.assert_allclose(d.origin[:2], o[:2], atol=1e-8, rtol=0)
    assert d.info()["origin"]["lat_deg"] == d.origin[0] and "mean" in d.info()["origin_source"]
    # later fixes: NED about the mean (the frame moved by the mean static error)
    for out, p in zip(outs[1:], moving):
        ref = pymap3d.geodetic2ned(*pymap3d.ned2geodetic(*p, lat0, lon0, h0), *o)
        np.testing.assert_allclose(out.values[:3], ref, atol=2e-3)
    np.testing.assert_allclose(np.array([out.values[:3] for out in outs[1:]]),
                               moving - static.mean(axis=0), atol=0.05)   # ~ the shift of the frame


def test_log_line_with_sentence_goes_through_the_log_parser():
    m = parse_line(f"3.5,gps,{GGA}")
    assert m.values == (GGA,)
    assert dec(origin=ORIGIN, epoch=["GGA"]).decode(m) is not None


def test_bad_params_are_config_errors():
    from pydantic import ValidationError
    with pytest.raises(ValidationError, match="unknown sentence"):
        NmeaParams(epoch=["GGA", "XYZ"])
    with pytest.raises(ValidationError, match="needs GGA"):
        NmeaParams(epoch=["RMC"])


def test_bad_fixes_in_the_static_window_do_not_move_it_into_the_drive():
    """The origin's window is the first origin_s seconds of GPS messages, valid or not: when every fix in it
    is bad (checksums), the first valid fix after it is the origin on its own, and origin_source says so.
    (A window opened at the first valid fix would average the drive that followed.)"""
    lat0, lon0, h0 = 35.0, 139.0, 40.0
    drive = np.array([[0.0, 0.0, 0.0]] * 10 + [[10.0 * k, 0.0, 0.0] for k in range(1, 11)])
    sentences = _fixes(lat0, lon0, h0, drive)
    d = dec(origin_s=9.0)
    outs = []
    for k, s in enumerate(sentences):
        t = float(k // 2)
        if t < 9.0:                                  # the static start: every sentence's checksum broken
            s = s[:-2] + ("00" if s[-2:] != "00" else "01")
            with pytest.raises(MalformedMessage):
                d.decode(msg(s, t))
            continue
        out = d.decode(msg(s, t))
        if out is not None:
            outs.append(out)
    assert "first valid fix, at 9.000 s" in d.info()["origin_source"]
    assert outs[0].t == 9.0 and outs[0].values[9] == 1.0        # the origin fix: one fix, not an average
    np.testing.assert_allclose(d.origin, pymap3d.ned2geodetic(*drive[9], lat0, lon0, h0), atol=1e-3, rtol=0)
    np.testing.assert_allclose(outs[-1].values[:3], drive[-1] - drive[9], atol=2e-3)


def _epoch_with_quality(d: NmeaDecoder, q: int):
    gga = sentence(f"GPGGA,123519,4807.038,N,01131.000,E,{q},08,0.9,545.4,M,46.9,M,,")
    assert d.decode(msg(gga)) is None
    return d.decode(msg(RMC))


@pytest.mark.parametrize("q", [6, 7, 8])
@pytest.mark.parametrize("min_quality", [1, 4])
def test_dead_reckoning_manual_and_simulated_fixes_are_refused(q, min_quality):
    # GGA quality is a code: 6 (dead reckoning), 7 (manual), 8 (simulation) are no measurement, whatever
    # min_quality is (an ordinal test would pass them at min_quality 4, "RTK only", as better than RTK)
    d = dec(origin=ORIGIN, min_quality=min_quality)
    with pytest.raises(RejectedMessage, match=f"quality {q} .*not a measured fix"):
        _epoch_with_quality(d, q)
    assert d.counters["invalid"] == 1


def test_min_quality_ranks_the_measured_fixes_and_qualities_lists_them_exactly():
    passed = {q for q in range(1, 9) if _passes(dict(min_quality=4), q)}
    assert passed == {4, 5}
    assert {q for q in range(1, 9) if _passes({}, q)} == {1, 2, 3, 4, 5}
    assert {q for q in range(1, 9) if _passes(dict(qualities=[1, 2, 6]), q)} == {1, 2, 6}
    with pytest.raises(ValueError, match="not both"):
        NmeaParams(min_quality=2, qualities=[1])
    with pytest.raises(ValueError):
        NmeaParams(qualities=[0])
    with pytest.raises(ValueError):
        NmeaParams(min_quality=6)


def _passes(params: dict, q: int) -> bool:
    try:
        return _epoch_with_quality(dec(origin=ORIGIN, **params), q) is not None
    except RejectedMessage:
        return False


def _drive(d: NmeaDecoder, sentences, t0: float = 0.0):
    outs = [d.decode(msg(s, t0 + float(k // 2))) for k, s in enumerate(sentences)]
    return [o for o in outs if o is not None]


def test_a_gps_stream_starting_late_ends_the_window_at_the_first_moving_fix():
    """The GPS stream starts 30 s after the IMU, 10 s before the drive; a window of origin_s (39 s) of GPS
    messages would run 29 s into the drive, average it into the origin (76 m off) and start the filter
    there at rest. The first moving fix (RMC speed) ends the window: the origin is the mean of
    the static fixes, and that fix is emitted with its velocity (the filter starts where the car is)."""
    lat0, lon0, h0 = 35.1, 139.1, 40.0
    rng = np.random.default_rng(2)
    static = rng.normal(0, 2.0, (10, 3))
    v = 1.0 + np.arange(10.0)                                 # m/s, east, from the 11th fix on
    moving = np.c_[np.zeros(10), np.cumsum(v), np.zeros(10)]
    knots = [0.1] * 10 + list(v / KNOT)
    d = dec(origin_s=39.0)
    outs = _drive(d, _fixes(lat0, lon0, h0, np.vstack([static, moving]), knots=knots), t0=30.0)
    first = outs[0]
    assert first.t == 40.0 and first.values[9] == 1.0          # the moving fix, its own sd
    np.testing.assert_allclose(first.values[3:5], [0.0, 1.0], atol=1e-3)   # with its velocity
    ecef = np.array([pymap3d.geodetic2ecef(*pymap3d.ned2geodetic(*p, lat0, lon0, h0)) for p in static]).mean(axis=0)
    np.testing.assert_allclose(d.origin, pymap3d.ecef2geodetic(*ecef), atol=1e-3, rtol=0)
    np.testing.assert_allclose(first.values[:3], moving[0] - static.mean(axis=0), atol=0.05)
    assert len(outs) == 10 and d.counters["moving_start"] == 1 and "static fixes before" in d.info()["origin_source"]
    (w,) = d.take_events()
    assert w.kind == "warning" and "static start ended at 40.000 s" in w.detail and d.take_events() == []


def test_a_gps_stream_without_a_static_fix_starts_from_its_first_fix_and_velocity():
    lat0, lon0, h0 = 35.1, 139.1, 40.0
    moving = np.c_[np.zeros(5), 10.0 * np.arange(5.0), np.zeros(5)]
    d = dec(origin_s=39.0)
    outs = _drive(d, _fixes(lat0, lon0, h0, moving, knots=[10.0 / KNOT] * 5), t0=45.0)
    assert outs[0].t == 45.0 and outs[0].values[:3] == (0.0, 0.0, 0.0) and outs[0].values[9] == 1.0
    np.testing.assert_allclose(outs[0].values[3:5], [0.0, 10.0], atol=1e-3)
    np.testing.assert_allclose(d.origin[:2], pymap3d.ned2geodetic(0, 0, 0, lat0, lon0, h0)[:2], atol=1e-7)
    np.testing.assert_allclose(outs[-1].values[:3], moving[-1], atol=2e-3)
    assert "no static fix" in d.info()["origin_source"] and "no static GPS fix" in d.take_events()[0].detail


def test_static_speed_noise_does_not_end_the_window():
    lat0, lon0, h0 = 35.1, 139.1, 40.0
    d = dec(origin_s=9.0)
    outs = _drive(d, _fixes(lat0, lon0, h0, np.zeros((12, 3)), knots=[0.9] * 12))   # 0.46 m/s: at rest
    assert outs[0].t == 9.0 and outs[0].values[9] == 10.0 and d.take_events() == []
    assert "moving_start" not in d.info()
