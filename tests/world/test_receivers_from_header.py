"""Paper 003's pose system (configs/ultrasonic_3d_pose.yaml, which names no receiver array) on a walk whose
32 receivers are numbered in another order, listed in the recording's header: it reads the array from there
and meets Table III; a config naming the paper's numbering is refused against that header (exit 2) unless
it prefers its own; the array as a list or a file."""
from __future__ import annotations

import numpy as np
import pytest
from world_helpers import ROOT, edited, run, simulate

from fusion.api import BuildContext, ConfigError
from fusion.cli import main
from fusion_plugins.measurement.receiver_array import read_file, resolve_receivers
from fusion_plugins.simulators.arrival import truncated_icosahedron_normals

CONFIG = ROOT / "configs" / "ultrasonic_3d_pose.yaml"
VARIANT = ROOT / "scenarios" / "variants" / "ultrasonic_3d_walk_renumbered.yaml"
# paper 003, Table III (EKF): mean angle error 9.34 deg, maximum 21.1 deg (RMSE >= mean: a stricter bound)
TABLE_III_MEAN_DEG, TABLE_III_MAX_DEG = 9.34, 21.1


@pytest.fixture(scope="module")
def renumbered(tmp_path_factory):
    d = tmp_path_factory.mktemp("renumbered")
    return simulate(VARIANT, d / "walk.log")      # 300 s: the first minute's convergence weighs less


def test_header_lists_another_numbering(renumbered):
    from fusion.world import read_world

    normals = read_world(renumbered).receivers.value
    paper = truncated_icosahedron_normals()
    assert not np.allclose(normals, paper)                              # renumbered ...
    order = np.argmax(normals @ paper.T, axis=1)
    assert sorted(order) == list(range(32)) and np.allclose(normals, paper[order], atol=1e-8)   # ... same array


def test_pose_config_reads_the_array_from_the_header(renumbered, tmp_path):
    code, s = run(CONFIG, renumbered, tmp_path / "s.json")
    assert code == 0
    assert s["errors"]["attitude_rmse_deg"] <= TABLE_III_MEAN_DEG
    assert s["errors"]["attitude_max_deg"] <= TABLE_III_MAX_DEG
    assert s["info"]["us"]["measurement"]["receiver_array"]["source"] == "recording header"
    assert s["info"]["us"]["solver"]["start"].startswith("pose from the geometric fixes")   # how it started


def test_config_array_contradicting_the_header_is_refused(renumbered, tmp_path, capsys):
    cfg = edited(CONFIG, tmp_path / "c.yaml", recording=str(renumbered),
                 **{"sensors.us.model.receivers": "truncated_icosahedron"})
    code, _ = run(cfg, None, tmp_path / "s.json")
    err = capsys.readouterr().err
    assert code == 2 and "receivers" in err and "walk.log:17" in err and "prefer" in err
    assert main(["validate", str(cfg)]) == 2
    cfg = edited(cfg, tmp_path / "c2.yaml", prefer={"receivers": "config"})
    assert main(["validate", str(cfg)]) == 0


def test_array_as_a_list_or_a_file(tmp_path):
    paper = truncated_icosahedron_normals()
    f = tmp_path / "array.txt"
    f.write_text("# my array\n" + "\n".join(f"{i + 1}: {x} {y} {z}" for i, (x, y, z) in enumerate(paper[::-1])))
    assert np.allclose(read_file(f), paper[::-1])
    ctx = BuildContext(base_dir=str(tmp_path))
    n, info = resolve_receivers("array.txt", ctx, "direction")
    assert np.allclose(n, paper[::-1]) and info["source"] == "config"
    n, _ = resolve_receivers([list(2 * v) for v in paper], ctx, "direction")
    assert np.allclose(n, paper)                                         # normalised
    f.write_text("1: 0 0 1\n3: 1 0 0\n")
    with pytest.raises(ConfigError, match="without a gap"):
        read_file(f)
    with pytest.raises(ConfigError, match="neither a known array"):
        resolve_receivers("dodecahedron", ctx, "direction")
    with pytest.raises(ConfigError, match="receiver array is unknown"):
        resolve_receivers(None, ctx, "direction")
