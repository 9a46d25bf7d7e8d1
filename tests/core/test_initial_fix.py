"""The initial belief from a first fix that carries more than a position (a GPS fix with velocity, the
``gps_fields`` decoder of an imported log with ``position_only_s: 0``): the position from the fix, the
velocity from the rows of h that select it, their covariance from R. Before, such a fix ended the run
("could not broadcast (3,) into (5,)")."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from fusion.config import load_system
from fusion.logformat import iter_messages
from fusion.run import Loop
from fusion.sources.recording import open_lines

ROOT = Path(__file__).resolve().parents[2]


def _system(tmp_path: Path):
    cfg = yaml.safe_load((ROOT / "configs" / "ardupilot_ins_gps_mag.yaml").read_text())
    cfg["recording"] = str(ROOT / "recordings" / "flight_synthetic.log")
    for s in cfg["sensors"].values():
        dec = s.get("decoder")
        if isinstance(dec, dict) and "position_only_s" in dec:
            dec["position_only_s"] = 0.0
    path = tmp_path / "ap.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return load_system(path)


def test_first_fix_with_velocity_sets_position_and_velocity(tmp_path):
    system = _system(tmp_path)
    sched = Loop(system)
    for item in iter_messages(open_lines(system.recording)):
        if getattr(item, "sensor", None) in ("truth", "reference") or isinstance(item, Exception):
            continue
        list(sched.push(item))
        if sched.belief is not None:
            break
    fix = sched.startup.latest_fix
    assert fix is not None and len(fix.z) == 5          # [pn pe pd vn ve]: the fix carried velocity
    x0, P0 = sched.startup.initial()
    lay = system.layout
    p, v = lay["p"], lay["v"]
    np.testing.assert_allclose(x0[p.start:p.start + 3], fix.model.position_from(fix.z, x0), atol=1e-12)
    np.testing.assert_allclose(x0[v.start:v.start + 2], fix.z[3:5], atol=1e-12)
    R = np.asarray(fix.R)
    np.testing.assert_allclose(P0[v.start:v.start + 2, v.start:v.start + 2], R[3:5, 3:5], atol=1e-15)
    np.testing.assert_allclose(P0[p.start:p.start + 3, p.start:p.start + 3], R[:3, :3], atol=1e-15)
    assert P0[v.start + 2, v.start + 2] == system.P0[v.start + 2, v.start + 2]   # vd: not in the fix


def test_the_run_from_such_a_fix_completes(tmp_path):
    from fusion import pipeline

    result = pipeline.run(_system(tmp_path), _system(tmp_path).recording)
    assert result.stats.estimates > 0 and result.stats.last_finite
