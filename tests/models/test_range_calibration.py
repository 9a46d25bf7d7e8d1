"""Range model: per-beacon calibration (measured = scale x distance + bias), the tag's lever arm, and
multi-pair range lines under a repeating ``# fields uwb beacon range ...`` header, end to end."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from fusion.api import BuildContext, ConfigError, Message, StateLayout
from fusion.cli import main
from fusion_plugins.measurement.range import RangeModel

ROOT = Path(__file__).resolve().parents[2]
B3D = {"B1": np.array([0.0, 0.0, -2.0]), "B2": np.array([10.0, 0.0, -2.5]), "B3": np.array([10.0, 8.0, -1.0]),
       "B4": np.array([0.0, 8.0, -3.0])}
CAL = {"B1": {"bias": 0.25, "scale": 1.01}, "B3": {"bias": -0.1, "scale": 0.995}}


def _model(layout: str, **params) -> RangeModel:
    return RangeModel(RangeModel.Params(**params), BuildContext(layout=StateLayout.parse(layout), beacons=B3D))


def _numeric_jacobian(f, x, eps=1e-6):
    return np.column_stack([(f(x + eps * e) - f(x - eps * e)) / (2 * eps) for e in np.eye(len(x))])


def test_calibrated_multi_pair_prediction_by_closed_form():
    m = _model("p:3 v:3", calibration=CAL)
    obs = m.observe(Message(1.0, "uwb", ("B1", 5.0, "B2", 6.0, "B3", 7.0)))
    x = np.array([3.0, 2.0, -1.0, 0.5, 0.0, 0.0])
    d = np.array([np.linalg.norm(x[:3] - B3D[b]) for b in ("B1", "B2", "B3")])
    want = np.array([1.01 * d[0] + 0.25, d[1], 0.995 * d[2] - 0.1])
    np.testing.assert_allclose(obs.model.h(x), want, rtol=1e-14)
    np.testing.assert_allclose(obs.z, [5.0, 6.0, 7.0])
    X = np.stack([x, x + 0.3, x - 0.2])                       # vectorised over leading axes
    np.testing.assert_allclose(obs.model.h(X)[1], obs.model.h(X[1]))
    np.testing.assert_allclose(obs.model.jacobian(x), _numeric_jacobian(obs.model.h, x), atol=1e-8)


def test_lever_arm_rotated_by_the_attitude():
    lever = [0.4, -0.1, 0.3]                                   # m, body FRD
    m = _model("p:3 v:3 q:4", lever_arm=lever, calibration=CAL)
    b = m.observe(Message(0.0, "uwb", ("B1", 1.0, "B3", 2.0, "B4", 3.0))).model
    rot = Rotation.from_euler("ZYX", [70.0, 10.0, -5.0], degrees=True)   # yaw, pitch, roll
    q = rot.as_quat()[[3, 0, 1, 2]]
    x = np.concatenate([[2.0, 3.0, -1.5], [0.0, 0.0, 0.0], q])
    tag = x[:3] + rot.apply(lever)                              # C_b^n l: body to NED
    d = np.array([np.linalg.norm(tag - B3D[k]) for k in ("B1", "B3", "B4")])
    np.testing.assert_allclose(b.h(x), [1.01 * d[0] + 0.25, 0.995 * d[1] - 0.1, d[2]], rtol=1e-13)
    np.testing.assert_allclose(b.jacobian(x), _numeric_jacobian(b.h, x), atol=1e-7)


@pytest.mark.parametrize("layout,params,what", [
    ("p:3 v:3", {"calibration": {"B9": {"bias": 0.1}}}, "B9"),
    ("p:3 v:3", {"lever_arm": [0.1, 0.0, 0.0]}, "lever_arm needs"),
    ("p:2 v:2", {"lever_arm": [0.1, 0.0, 0.0]}, "lever_arm needs"),
])
def test_bad_calibration_is_a_config_error(layout, params, what):
    with pytest.raises(ConfigError, match=what):
        _model(layout, **params)


def test_scale_must_be_positive():
    with pytest.raises(Exception, match="greater than 0"):
        RangeModel.Params(calibration={"B1": {"scale": 0.0}})


# --------------------------------------------------------------------------- end to end through the CLI
def _recording(span=20.0):
    head, body = [], []
    for line in (ROOT / "recordings" / "uwb_route1.log").read_text().splitlines():
        if line.startswith("#"):
            head.append(line)
        elif float(line.split(",")[0]) <= span:
            body.append(line)
    return head, body


def _run(tmp_path, name, log_lines, config_over=None, exit_code=0):
    cfg = yaml.safe_load((ROOT / "configs" / "uwb_pv_ukf.yaml").read_text())
    cfg["recording"] = str((tmp_path / f"{name}.log").resolve())
    if config_over:
        cfg["sensors"]["uwb"].update(config_over)
    (tmp_path / f"{name}.log").write_text("\n".join(log_lines) + "\n")
    (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(cfg))
    js = tmp_path / f"{name}.json"
    assert main(["run", str(tmp_path / f"{name}.yaml"), "--summary-json", str(js), "--quiet", "--no-progress"]) \
        == exit_code
    return json.loads(js.read_text())


def _pairs(body):
    """Each two consecutive ranges as one two-pair line at the second's time (truth lines kept)."""
    out, pending = [], None
    for line in body:
        p = line.split(",")
        if p[1] != "uwb":
            out.append(line)
        elif pending is None:
            pending = p
        else:
            out.append(",".join([p[0], "uwb", pending[2], pending[3], p[2], p[3]]))
            pending = None
    return out


def test_multi_pair_lines_with_a_repeating_fields_header(tmp_path):
    head, body = _recording()
    paired = _pairs(body)
    n_lines = sum(1 for line in paired if ",uwb," in line)
    rep = [h if h != "# fields uwb beacon range" else "# fields uwb beacon range ..." for h in head]
    res = _run(tmp_path, "rep", rep + paired)
    s = res["sensors"]["uwb"]
    assert s["malformed"] == 0 and s["received"] == n_lines and s["used"] >= n_lines - 2
    single = _run(tmp_path, "single", head + body)["errors"]["position_rmse_m"]
    assert res["errors"]["position_rmse_m"] < 1.5 * single
    # without the '...' the header names one pair: every two-pair line is malformed (the behaviour before),
    # so no estimate is made: exit 2
    assert _run(tmp_path, "fixed", head + paired, exit_code=2)["sensors"]["uwb"]["malformed"] == n_lines


def test_calibration_undoes_biased_ranges(tmp_path):
    head, body = _recording()
    cal = {"B1": (1.02, 0.35), "B2": (0.98, -0.3), "B3": (1.0, 0.4), "B4": (1.01, 0.0)}
    biased = []
    for line in body:
        p = line.split(",")
        if p[1] == "uwb":
            s, b = cal[p[2]]
            p[3] = f"{s * float(p[3]) + b:.6f}"
        biased.append(",".join(p))
    base = _run(tmp_path, "base", head + body)["errors"]["position_rmse_m"]
    raw = _run(tmp_path, "raw", head + biased, exit_code=4)["errors"]["position_rmse_m"]   # degraded, and said
    fixed = _run(tmp_path, "cal", head + biased,
                 {"model": {"type": "range", "calibration": {k: {"scale": s, "bias": b} for k, (s, b) in cal.items()}}})
    assert raw > 2.0 * base                       # the biases spoil the fix ...
    assert fixed["errors"]["position_rmse_m"] < 1.15 * base   # ... and the calibration undoes them
