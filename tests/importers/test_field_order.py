"""A ``# fields`` line names a sensor's values in the order a component reads them (fusion run reads them by
position): a CSV mapping that lists the IMU's columns gyro first is written accelerometer first, each value
under its own name; a recording whose ``# fields imu`` line is reordered is refused by ``fusion run`` (exit 2),
naming the file, the line, the sensor, the order given and the order read."""
from __future__ import annotations

import textwrap

import numpy as np

from import_helpers import ROOT, Recording, fusion_import
from fusion.cli import main
from fusion.importers.field_order import reading_order


def test_known_orders():
    assert reading_order(("gx", "gy", "gz", "ax", "ay", "az")) == ("ax", "ay", "az", "gx", "gy", "gz")
    assert reading_order(("ax", "ay", "az", "gx", "gy", "gz")) is None        # already in order
    assert reading_order(("mz", "my", "mx")) == ("mx", "my", "mz")
    assert reading_order(("foo", "bar")) is None                              # no component reads that set


def test_csv_mapping_gyro_first_is_written_in_the_order_read(tmp_path, capsys):
    rng = np.random.default_rng(1)
    v = rng.normal(size=(20, 6))           # columns: acc x y z, gyro x y z
    rows = "\n".join(f"{0.01 * i:.2f}," + ",".join(f"{x:.6f}" for x in r) for i, r in enumerate(v))
    (tmp_path / "d.csv").write_text("t,acx,acy,acz,gyx,gyy,gyz\n" + rows + "\n")
    (tmp_path / "m.yaml").write_text(textwrap.dedent("""\
        time: {column: t, unit: s, zero: none}
        sensors:
          imu:
            fields: {gx: gyx, gy: gyy, gz: gyz, ax: acx, ay: acy, az: acz}
        """))
    out = tmp_path / "o.log"
    assert fusion_import(tmp_path / "d.csv", "--map", tmp_path / "m.yaml", "-o", out) == 0
    assert "written as ax ay az gx gy gz" in capsys.readouterr().err
    rec = Recording(out)
    assert rec.header.fields["imu"] == ("ax", "ay", "az", "gx", "gy", "gz")
    np.testing.assert_allclose(rec.values("imu"), v, atol=1e-6)          # each value under its own name


def test_run_refuses_a_reordered_imu_fields_line(tmp_path, capsys):
    src = (ROOT / "recordings" / "flight_synthetic.log").read_text().splitlines()
    i = src.index("# fields imu ax ay az gx gy gz")
    src[i] = "# fields imu gx gy gz ax ay az"
    bad = tmp_path / "swapped.log"
    bad.write_text("\n".join(src) + "\n")
    assert main(["run", str(ROOT / "configs" / "px4_ins_gps_mag.yaml"), "--input", str(bad), "-q"]) == 2
    err = capsys.readouterr().err
    assert f"{bad} line {i + 1}" in err and "imu gx gy gz ax ay az" in err and "(ax ay az gx gy gz)" in err
