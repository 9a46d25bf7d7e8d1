"""Wiring errors a user can act on, exit 2 with file:line: a ``kf`` given a non-linear model, a sensor
without noise whose model carries none, a misspelt hook in an installed plugin package."""
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from fusion.api import ConfigError, MeasurementModel
from fusion.cli import main
from fusion.config import load_system
from fusion.registry import make_plugin_manager

ROOT = Path(__file__).resolve().parents[2]
CONFIG = """\
name: demo
beacons: {B1: [0, 0], B2: [10, 0], B3: [10, 10]}
process: {type: pv, dims: 2, spectral_density: 0.5}
initial: {mean: {p: [1, 2], v: [0, 0]}, sd: {p: 2.0, v: 1.0}}
filter: kf
sensors:
  uwb: {model: range, noise: {sd: 0.1}}
"""


def test_kf_with_a_non_linear_measurement_model_is_exit_2_at_the_filter_line(tmp_path, capsys):
    path = tmp_path / "sys.yaml"
    path.write_text(CONFIG)
    with pytest.raises(ConfigError, match=r"sys.yaml:5: filter: filter 'kf' needs linear measurement models; "
                                          r"sensor 'uwb' uses 'range', which is not linear"):
        load_system(path)
    assert main(["validate", str(path)]) == 2
    assert "sys.yaml:5" in capsys.readouterr().err
    # the same system with ekf wires: the rule is about linearity only
    path.write_text(CONFIG.replace("filter: kf", "filter: ekf"))
    assert load_system(path).filter.name == "ekf"


def test_kf_accepts_models_declaring_linear(tmp_path):
    path = tmp_path / "sys.yaml"
    path.write_text(CONFIG.replace("uwb: {model: range, noise: {sd: 0.1}}", "gps: {model: position, noise: {sd: 0.5}}"))
    system = load_system(path)
    assert system.filter.name == "kf" and system.sensors["gps"].model.linear


def test_kf_on_the_command_line_with_a_non_linear_process_is_exit_2(tmp_path, capsys):
    out = tmp_path / "o.csv"
    assert main(["run", str(ROOT / "configs" / "abps_ins.yaml"), "--filter", "kf", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "filter (--filter): filter 'kf' needs a linear process model; process 'ins' is not linear" in err


class Barometer(MeasurementModel):
    """Height (m, up) from p_z: a model whose messages never carry R (carries_R left at its default)."""

    name = "test_baro"
    dim = 1

    def h(self, x):
        return -np.asarray(x)[..., 2:3]


def test_a_sensor_without_noise_whose_model_carries_none_is_refused_at_its_line(tmp_path):
    _, reg = make_plugin_manager()
    reg.add(Barometer)
    path = tmp_path / "baro.yaml"
    path.write_text(textwrap.dedent("""\
        name: baro
        process: {type: pv, dims: 3}
        filter: ekf
        sensors:
          baro:
            model: test_baro
        """))
    with pytest.raises(ConfigError, match=r"baro.yaml:5: sensors.baro: a measurement sensor needs 'noise:' "
                                          r"\(sd or R\): its model 'test_baro' takes no covariance"):
        load_system(path, registry=reg)
    path.write_text(path.read_text() + "    noise: {sd: 0.5}\n")
    assert load_system(path, registry=reg).sensors["baro"].R[0, 0] == pytest.approx(0.25)


def _bad_package(site):
    pkg = site / "fusion_badhook"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "plugin.py").write_text(textwrap.dedent("""\
        from fusion import hookimpl


        @hookimpl
        def fusion_register_componets(registry):   # misspelt on purpose
            pass
        """))
    info = site / "fusion_badhook-1.2.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: fusion-badhook\nVersion: 1.2\n")
    (info / "entry_points.txt").write_text("[fusion]\nbadhook = fusion_badhook.plugin\n")


def test_a_misspelt_hook_in_an_installed_package_is_exit_2_naming_it_and_the_way_out(tmp_path):
    site = tmp_path / "site"
    _bad_package(site)
    env = {k: v for k, v in os.environ.items() if k != "FUSION_DISABLE_PLUGIN_AUTOLOAD"}
    env["PYTHONPATH"] = os.pathsep.join([str(site), env.get("PYTHONPATH", "")])
    cmd = [sys.executable, "-c", "import sys; from fusion.cli import main; sys.exit(main())", "plugins"]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    assert proc.returncode == 2, proc.stderr
    err = proc.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert f"{site / 'fusion_badhook' / 'plugin.py'}:4: hook 'fusion_register_componets' is not a fusion hook" in err
    assert "did you mean 'fusion_register_components'?" in err
    assert "plugin 'badhook' of the installed package 'fusion-badhook 1.2'" in err
    assert "FUSION_BLOCK_PLUGINS=badhook" in err
    proc = subprocess.run(cmd, env={**env, "FUSION_BLOCK_PLUGINS": "badhook"}, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


EKF = CONFIG.replace("filter: kf", "filter: ekf")


@pytest.mark.parametrize("old, new, message", [
    # a noise sd list of the wrong length says how many it needs (not "1 or 1 values")
    ("noise: {sd: 0.1}", "noise: {sd: [0.1, 0.2]}",
     r"sys.yaml:7: sensors.uwb.noise.sd: needs 1 value for this measurement model, got 2"),
    ("noise: {sd: 0.1}", "noise: {sd: [0.1, 0.2, 0.3]}", r"needs 1 value for this measurement model, got 3"),
    ("spectral_density: 0.5", "spectral_density: [0.5, 0.5, 0.5]", r"spectral_density needs 1 or 2 values, got 3"),
    # beacons that are not coordinates
    ("B2: [10, 0]", "B2: [true, 0]", r"sys.yaml:2: beacons.B2.0: .*a coordinate must be a number, got true"),
    ("B2: [10, 0]", "B2: [10, 0, 5]",
     r"beacon 'B2' has 3 coordinates and 'B1' 2: give every beacon 2 \(x y\) or every beacon 3"),
    ("B2: [10, 0]", "B2: [1.0e200, 0]", r"beacon 'B2': a coordinate beyond 1e\+08 m"),
    # values whose squares overflow
    ("mean: {p: [1, 2]", "mean: {p: [1.0e300, 2]", r"sys.yaml:4: initial.mean.p: 1e\+300 is beyond 1e\+12 in magnitude"),
    ("spectral_density: 0.5", "spectral_density: 1.0e300", r"spectral_density must be at most 1e\+12 m\^2/s\^3"),
])
def test_a_bad_value_is_refused_with_its_line_and_reason(tmp_path, old, new, message):
    path = tmp_path / "sys.yaml"
    assert old in EKF
    path.write_text(EKF.replace(old, new))
    with pytest.raises(ConfigError, match=message):
        load_system(path)


def test_the_unchanged_config_of_those_cases_wires():
    """The cases above fail for their value alone: the config they edit is valid."""
    assert load_system_text(EKF).beacons["B2"].tolist() == [10.0, 0.0]


def load_system_text(text):
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "sys.yaml"
        path.write_text(text)
        return load_system(path)
