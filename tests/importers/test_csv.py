"""``fusion import`` of CSV datasets through a mapping file: the shipped example (docs/examples/uwb_dataset,
made from recordings/uwb_route1.log by scripts/make_import_example.py) must give back that recording's lines,
and each mapping feature is checked against values computed here from the CSV text."""
from __future__ import annotations

import datetime as dt
import json
import textwrap

import numpy as np
import pytest

from import_helpers import ROOT, Recording, fusion_import, one_error_line
from fusion.cli import main

EX = ROOT / "docs" / "examples" / "uwb_dataset"
ORIGINAL = ROOT / "recordings" / "uwb_route1.log"


def _original(span: float = 20.0) -> tuple[list[tuple[float, str, float]], np.ndarray]:
    """(ranges, truth rows) of the first ``span`` s of the simulated recording the example was made from."""
    ranges, truth = [], []
    for line in ORIGINAL.read_text().splitlines():
        if line.startswith("#"):
            continue
        p = line.split(",")
        if float(p[0]) > span:
            break
        if p[1] == "uwb":
            ranges.append((float(p[0]), p[2], float(p[3])))
        elif p[1] == "truth":
            truth.append([float(x) for x in (p[0], *p[2:])])
    return ranges, np.array(truth)


@pytest.fixture(scope="module")
def example(tmp_path_factory):
    out = tmp_path_factory.mktemp("csv") / "uwb.log"
    assert fusion_import(EX / "ranges.csv", "--map", EX / "mapping.yaml", "-o", out) == 0
    return out


def test_example_gives_back_the_recording_it_was_made_from(example):
    rec = Recording(example)
    ranges, truth = _original()
    assert rec.header.fields["uwb"] == ("beacon", "range") and "uwb" in rec.header.repeating
    got = [(t, row[0], row[1]) for t, row in zip(rec.times("uwb"), rec.rows["uwb"])]
    assert len(got) == len(ranges)                            # the NaN/empty dropout rows give no line
    for (t, b, r), (t0, b0, r0) in zip(got, ranges):
        assert b == b0 and abs(t - t0) < 1e-6 and abs(r - r0) < 1e-6   # ISO ms stamps; mm with 3 decimals
    assert rec.header.fields["truth"] == ("px", "py", "vx", "vy")
    np.testing.assert_allclose(rec.times("truth"), truth[:, 0], atol=1e-6)   # the 2.0 s clock offset undone
    np.testing.assert_allclose(rec.values("truth"), truth[:, 1:], atol=1e-6)
    assert "# beacon B3: 30 20 0" in rec.comments
    assert rec.header.meta["time_zero"].startswith("2024-03-05T10:15:02.250")


def test_run_on_the_imported_example_matches_the_recording(example, tmp_path):
    """Two commands from CSV to an error table: the errors equal those of the original recording's span."""
    cut = tmp_path / "cut.log"
    lines = [line for line in ORIGINAL.read_text().splitlines()
             if line.startswith("#") or float(line.split(",")[0]) <= 20.0]
    cut.write_text("\n".join(lines) + "\n")
    res = {}
    for name, log in (("imported", example), ("original", cut)):
        js = tmp_path / f"{name}.json"
        assert main(["run", str(ROOT / "configs" / "uwb_pv_ukf.yaml"), "--input", str(log), "--summary-json", str(js),
                     "--quiet", "--no-progress"]) == 0
        res[name] = json.loads(js.read_text())
    a, b = res["imported"]["errors"], res["original"]["errors"]
    assert a["position_rmse_m"] == pytest.approx(b["position_rmse_m"], rel=1e-4)
    assert a["velocity_rmse_mps"] == pytest.approx(b["velocity_rmse_mps"], rel=1e-4)


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text).lstrip())
    return p


def test_fields_scales_offsets_units_and_time_in_microseconds(tmp_path):
    csv = _write(tmp_path, "imu.csv", """
        stamp_us;acc_x_g;acc_y_g;acc_z_g;gyr_x_dps;gyr_y_dps;gyr_z_dps;temp
        1000000;0.01;-0.02;-1.0;1.5;-3;0.25;20
        1010000;0.02;-0.01;-0.99;1.0;-2;0.5;20
        1020000;;-0.01;-0.99;1.0;-2;0.5;20
        1030000;0.03;0.0;-1.01;0.0;0;0;21
    """)
    g, d2r = 9.80665, np.pi / 180
    mp = _write(tmp_path, "map.yaml", f"""
        time: {{column: stamp_us, unit: us}}
        sensors:
          imu:
            fields: {{ax: acc_x_g, ay: acc_y_g, az: acc_z_g, gx: gyr_x_dps, gy: gyr_y_dps, gz: gyr_z_dps}}
            scale: {{ax: {g}, ay: {g}, az: {g}, gx: {d2r!r}, gy: {d2r!r}, gz: {d2r!r}}}
            time_offset: 0.005
          temp:
            fields: {{t_c: temp}}
            offset: 273.15
    """)
    out = tmp_path / "o.log"
    assert fusion_import(csv, "--map", mp, "-o", out) == 0
    rec = Recording(out)
    # the row with an empty cell gives no imu sample; times from 1e6 us, zero at the first row, +5 ms
    np.testing.assert_allclose(rec.times("imu"), [0.005, 0.015, 0.035], atol=1e-9)
    np.testing.assert_allclose(rec.values("imu")[0], [0.01 * g, -0.02 * g, -1.0 * g, 1.5 * d2r, -3 * d2r, 0.25 * d2r],
                               rtol=1e-11)
    np.testing.assert_allclose(rec.values("temp")[:, 0], [293.15, 293.15, 293.15, 294.15], rtol=1e-12)
    np.testing.assert_allclose(rec.times("temp"), [0.0, 0.01, 0.02, 0.03], atol=1e-9)


def test_time_slice_converts_only_its_rows_and_selects_sensors(tmp_path):
    n = 2000
    t = np.arange(n) * 0.01
    csv = tmp_path / "big.csv"
    csv.write_text("t,a,b\n" + "".join(f"{x:.2f},{i},{2 * i}\n" for i, x in enumerate(t)) + "30,not,numbers\n")
    mp = _write(tmp_path, "m.yaml", """
        time: {column: t, unit: s, zero: none}
        sensors:
          a: {fields: {v: a}}
          b: {fields: {v: b}}
    """)
    out = tmp_path / "o.log"
    # the cells of the last row (not numbers) are never converted: its time is past the span's end
    assert fusion_import(csv, "--map", mp, "-o", out, "--start", "1", "--end", "3", "--sensors", "b") == 0
    rec = Recording(out)
    assert set(rec.t) == {"b"}
    sel = (t >= 1 - 1e-9) & (t <= 3 + 1e-9)
    np.testing.assert_allclose(rec.times("b"), t[sel], atol=1e-9)
    np.testing.assert_allclose(rec.values("b")[:, 0], 2 * np.flatnonzero(sel))


def test_iso_times_naive_are_utc_and_zero_by_date(tmp_path):
    csv = _write(tmp_path, "g.csv", """
        when,lat,lon
        2023-07-01 12:00:00.5,45.1,7.6
        2023-07-01T12:00:01.75+02:00,45.2,7.7
    """)
    mp = _write(tmp_path, "m.yaml", """
        time: {column: when, unit: iso, zero: "2023-07-01T12:00:00Z"}
        sensors:
          gps: {fields: {lat: lat, lon: lon}}
    """)
    out = tmp_path / "o.log"
    assert fusion_import(csv, "--map", mp, "-o", out) == 0
    rec = Recording(out)
    second = (dt.datetime(2023, 7, 1, 10, 0, 1, 750000, tzinfo=dt.timezone.utc)
              - dt.datetime(2023, 7, 1, 12, tzinfo=dt.timezone.utc)).total_seconds()
    # times sorted: the +02:00 row is 2 h earlier than the naive (UTC) one
    np.testing.assert_allclose(rec.times("gps"), [second, 0.5], atol=1e-6)
    np.testing.assert_allclose(rec.column("gps", "lat"), [45.2, 45.1])


@pytest.mark.parametrize("zero", ["2023-07-01T12:00:00Z", '"2023-07-01T12:00:00Z"', '"2023-07-01T14:00:00+02:00"',
                                  "1688212800", "2023-07-01 12:00:00"])
def test_a_date_time_zero_for_numeric_epoch_times_quoted_or_not(tmp_path, zero):
    """time.zero as a date-time for a column of Unix-epoch nanoseconds; YAML reads an unquoted one as a
    date-time object (not refused as 'not a valid string'), and a quoted one is accepted though the column
    itself is not ISO text. Every spelling of the same instant gives the same times."""
    t0 = 1688212800  # 2023-07-01T12:00:00Z
    csv = _write(tmp_path, "e.csv", f"""
        t_ns,v
        {t0 * 10**9 + 250_000_000},1
        {t0 * 10**9 + 1_500_000_000},2
    """)
    mp = _write(tmp_path, "m.yaml", f"""
        time: {{column: t_ns, unit: ns, zero: {zero}}}
        sensors:
          x: {{fields: {{v: v}}}}
    """)
    out = tmp_path / "o.log"
    assert fusion_import(csv, "--map", mp, "-o", out) == 0
    np.testing.assert_allclose(Recording(out).times("x"), [0.25, 1.5], atol=1e-6)


@pytest.mark.parametrize("csv_text,map_text,expect", [
    ("t,a\n0,1\n", "time: {column: t}\nsensors: {x: {fields: {v: nope}}}\n", "no column 'nope'"),
    ("t,a\n0,1\n", "time: {column: t}\nsensors: {x: {fields: {v: a}, scal: 2}}\n", "unknown key"),
    ("t,a\n0,1\n", "sensors: {x: {fields: {v: a}}}\n", "no time column"),
    ("t,a\n0,1\n1,abc\n", "time: {column: t}\nsensors: {x: {fields: {v: a}}}\n", ":3: x.v: 'abc' is not a number"),
    ("t,a\n0,1\nyesterday,2\n", "time: {column: t}\nsensors: {x: {fields: {v: a}}}\n", ":3: time 'yesterday'"),
    ("t,a\n0,1\n", "time: {column: t}\nsensors: {truth: {fields: {v: a}}}\n", "not a usable sensor name"),
    ("t,a\n0,1\n", "time: [oops\n", "invalid YAML"),
])
def test_bad_mapping_or_data_is_one_error(tmp_path, capsys, csv_text, map_text, expect):
    csv = tmp_path / "d.csv"
    csv.write_text(csv_text)
    mp = tmp_path / "m.yaml"
    mp.write_text(map_text)
    assert fusion_import(csv, "--map", mp, "-o", tmp_path / "o.log") == 2
    assert expect in one_error_line(capsys)
    assert not (tmp_path / "o.log").exists()


def test_csv_without_mapping_and_binary_csv(tmp_path, capsys):
    csv = tmp_path / "d.csv"
    csv.write_text("t,a\n0,1\n")
    assert fusion_import(csv, "-o", tmp_path / "o.log") == 2
    assert "--map" in one_error_line(capsys)
    csv.write_bytes(b"\x00\x01\x02binary")
    mp = tmp_path / "m.yaml"
    mp.write_text("time: {column: t}\nsensors: {x: {fields: {v: a}}}\n")
    assert fusion_import(csv, "--map", mp, "-o", tmp_path / "o.log") == 2
    assert "binary" in one_error_line(capsys)


def test_pairs_with_sentinels_and_per_beacon_scale(tmp_path):
    csv = _write(tmp_path, "u.csv", """
        t;A;B;C
        0.00;1200;0;65535
        0.10;;3400.5;2000
        0.20;0;0;0
    """)
    mp = _write(tmp_path, "m.yaml", """
        time: {column: t}
        sensors:
          uwb:
            pairs: {A0: A, B0: B, C0: C}
            scale: {A0: 0.001, B0: 0.001, C0: 0.0005}
            valid: [0.01, 30]
    """)
    out = tmp_path / "o.log"
    assert fusion_import(csv, "--map", mp, "-o", out) == 0
    rec = Recording(out)
    assert rec.rows["uwb"] == [("A0", 1.2), ("B0", 3.4005, "C0", 1.0)]   # 0 and 65535 mm are no range
    np.testing.assert_allclose(rec.times("uwb"), [0.0, 0.1])


@pytest.mark.parametrize("n_rows", [1, 5, 20])
def test_a_short_file_with_one_ragged_row_is_read_by_its_header_delimiter(tmp_path, n_rows):
    """csv.Sniffer gives up on a short sample with one ragged row; splitting on whitespace would then
    blame the mapping ('no column time in ... columns: time,ax,...'). The header's delimiter is used
    instead."""
    rows = "\n".join(f"{0.01 * k:.2f},1,0,0,0,0,0" + (",9" if k == 0 else "") for k in range(n_rows))
    csv = _write(tmp_path, "s.csv", "time,ax,ay,az,gx,gy,gz\n" + rows + "\n")
    mp = _write(tmp_path, "m.yaml", """
        time: {column: time}
        sensors:
          imu: {fields: {ax: ax, ay: ay, az: az, gx: gx, gy: gy, gz: gz}}
    """)
    assert fusion_import(csv, "--map", mp, "-o", tmp_path / "o.log") == 0
    assert len(Recording(tmp_path / "o.log").times("imu")) == n_rows


def test_a_mapped_name_twice_in_the_header_is_refused(tmp_path, capsys):
    """Two columns of one name are refused, not the first taken silently."""
    csv = _write(tmp_path, "d.csv", "time,ax,ay,ax\n0,1,0,99\n0.01,1,0,99\n")
    mp = _write(tmp_path, "m.yaml", """
        time: {column: time}
        sensors:
          imu: {fields: {ax: ax, ay: ay}}
    """)
    assert fusion_import(csv, "--map", mp, "-o", tmp_path / "o.log") == 2
    assert "column 'ax' is in the header of d.csv 2 times (columns 1, 3)" in one_error_line(capsys)
    mp2 = _write(tmp_path, "m2.yaml", """
        time: {column: time}
        sensors:
          imu: {fields: {ax: 3, ay: ay}}
    """)
    assert fusion_import(csv, "--map", mp2, "-o", tmp_path / "o.log") == 0      # by number: the second one
    np.testing.assert_allclose(Recording(tmp_path / "o.log").column("imu", "ax"), [99, 99])
