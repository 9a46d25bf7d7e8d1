"""Config validation: every error names the file, the YAML line, the field and what is valid."""
import textwrap

import numpy as np
import pytest

from fusion.api import ConfigError
from fusion.config import load_system

GOOD = """\
name: demo
beacons: {B1: [0, 0], B2: [10, 0], B3: [10, 10], B4: [0, 10]}
process: {type: pv, dims: 2, spectral_density: 0.5}
initial:
  mean: {p: [1, 2], v: [0, 0]}
  sd: {p: 2.0, v: 1.0}
filter: ekf
sensors:
  uwb:
    model: range
    noise: {sd: 0.1}
    gate: {type: chi2, probability: 0.999}
"""


def write(tmp_path, text, name="sys.yaml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def test_good_config_wires(tmp_path):
    s = load_system(write(tmp_path, GOOD))
    assert s.layout.names == ("px", "py", "vx", "vy")
    np.testing.assert_allclose(s.x0, [1, 2, 0, 0])
    np.testing.assert_allclose(np.diag(s.P0), [4, 4, 1, 1])
    assert s.sensors["uwb"].R.shape == (1, 1) and s.sensors["uwb"].R[0, 0] == pytest.approx(0.01)


@pytest.mark.parametrize("old,new,expect", [
    ("filter: ekf", "filter: ukff", r"sys.yaml:7: filter: unknown filter 'ukff'; did you mean 'ukf'\?"),
    ("model: range", "model: rnge", r"sys.yaml:10: .*unknown measurement 'rnge'; did you mean 'range'"),
    ("noise: {sd: 0.1}", "noise: {R: [[1, 0], [0, 1]]}", r"sys.yaml:11: sensors.uwb.noise.R: must be 1 x 1"),
    ("mean: {p: [1, 2], v: [0, 0]}", "mean: {p: [1, 2, 3], v: [0, 0]}", r"sys.yaml:5: initial.mean.p: block 'p' has 2 elements, got 3"),
    ("sd: {p: 2.0, v: 1.0}", "sd: {p: 2.0, w: 1.0}", r"sys.yaml:6: initial.sd.w: state has no block 'w'"),
    ("spectral_density: 0.5}", "spectral_density: 0.5, speed: 3}", r"sys.yaml:3: process.speed: unknown key"),
    ("model: range", "model: {type: range, beacons: [B1, B9]}", r"unknown beacon\(s\) \['B9'\]"),
    ("probability: 0.999", "probability: 2.0", r"sys.yaml:12: sensors.uwb.gate.probability"),
    ("name: demo", "nme: demo", r"sys.yaml:1: nme: unknown key"),
])
def test_config_errors_name_file_line_field(tmp_path, old, new, expect):
    assert old in GOOD
    with pytest.raises(ConfigError, match=expect):
        load_system(write(tmp_path, GOOD.replace(old, new)))


def test_yaml_syntax_error_has_line(tmp_path):
    with pytest.raises(ConfigError, match=r"sys.yaml:3: invalid YAML"):
        load_system(write(tmp_path, "name: x\nprocess: pv\nsensors: a: b\n"))


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="no such file"):
        load_system(tmp_path / "nope.yaml")


def test_input_role_needs_input_process(tmp_path):
    text = GOOD.replace("  uwb:\n", "  imu: {role: input}\n  uwb:\n")
    with pytest.raises(ConfigError, match="takes no control input"):
        load_system(write(tmp_path, text))
