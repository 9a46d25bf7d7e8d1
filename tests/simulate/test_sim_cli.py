"""`fusion simulate`: the log contract, determinism, and clear errors (exit 2, one line)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import parse_log

from fusion.cli import main

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "scenarios" / "example_2d.yaml"


def _sim(tmp_path, *args) -> bytes:
    out = tmp_path / "out.log"
    assert main(["simulate", str(EXAMPLE), "-o", str(out), "--force", *args]) == 0
    return out.read_bytes()


def test_log_header_and_lines_follow_the_contract(tmp_path):
    text = _sim(tmp_path).decode("utf-8")
    lines = text.splitlines()
    assert lines[:3] == ["# fusion-log 1", "# scenario: example_2d", "# seed: 1"]
    msgs, header = parse_log(text)
    assert header.fields == {"uwb": ("beacon", "range"), "truth": ("px", "py", "vx", "vy")}
    assert "# beacon B1: 0 0 0" in lines
    body = [ln for ln in lines if not ln.startswith("#")]
    assert all(not ln.startswith("#") for ln in lines[lines.index(body[0]):])  # header first
    t = np.array([float(ln.split(",", 1)[0]) for ln in body])
    assert np.all(np.diff(t) >= 0)                                             # sorted by time
    assert all(len(ln.split(",")[0].split(".")[1]) == 6 for ln in body[:50])  # fixed precision
    truth_t = np.array([m.t for m in msgs["truth"]])
    assert np.allclose(np.diff(truth_t), 0.1)                                  # highest sensor rate
    assert all(m.values[0][0].isalpha() for m in msgs["uwb"])


def test_same_seed_same_bytes_other_seed_other_noise(tmp_path):
    a, b = _sim(tmp_path), _sim(tmp_path)
    assert a == b
    c = _sim(tmp_path, "--seed", "7")
    assert c != a and b"# seed: 7" in c
    truth = lambda data: [ln for ln in data.decode().splitlines() if ",truth," in ln]  # noqa: E731
    assert truth(a) == truth(c)                                                # same trajectory


def test_noise_off_and_stdout(tmp_path, capsys):
    assert main(["simulate", str(EXAMPLE), "-o", "-", "--noise", "off"]) == 0
    out = capsys.readouterr().out
    assert "# noise: off" in out and "# uwb range_noise_sd: 0.0" in out


@pytest.mark.parametrize("yaml, expect", [
    ("trajectory: {type: waypoints, waypoints: [[0, 0], [1, 0]]}\nsensors: {u: {type: range}}\nbogus: 1\n",
     "bad.yaml:3: bogus: unknown key"),
    ("trajectory: {type: waypoints, waypoints: [[0, 0], [1, 0]]}\nsensors:\n  u:\n    type: range\n"
     "    noise_sd: -1\n", "bad.yaml:5: sensors.u.noise_sd: Input should be greater than or equal to 0"),
    ("trajectory: {type: waypoints, waypoints: [[0, 0], [1, 0]]}\nsensors: {u: {type: rnage}}\n",
     "sensors.u.type: unknown simulator 'rnage'; did you mean 'range'?"),
    ("trajectory: {type: spiral}\nsensors: {u: {type: range}}\n", "bad.yaml:1: trajectory: Input tag 'spiral'"),
    ("trajectory:\n  type: waypoints\n  waypoints: [[0, 0], {at: [1, 0], stopp: 2}]\nsensors: {u: {type: range}}\n",
     "bad.yaml:3: trajectory.waypoints.1.stopp: unknown key"),
    ("trajectory: {type: waypoints, waypoints: [[0, 0], [1, 0]]}\nsensors: {u: {type: range, beacons: [X]}}\n",
     "unknown beacon"),
    ("dim: 2\nbeacons: {1A: [0, 0]}\ntrajectory: {type: waypoints, waypoints: [[0, 0], [1, 0]]}\n"
     "sensors: {u: {type: range}}\n", "must start with a letter"),
    ("a: [1, 2\n", "bad.yaml:2: invalid YAML"),
])
def test_bad_scenarios_exit_2_with_one_clear_line(tmp_path, capsys, yaml, expect):
    sc = tmp_path / "bad.yaml"
    sc.write_text(yaml)
    assert main(["simulate", str(sc), "-o", str(tmp_path / "x.log")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(sc) in err and expect in err, err
    assert not (tmp_path / "x.log").exists()


def test_missing_scenario_and_unwritable_output(tmp_path, capsys):
    assert main(["simulate", str(tmp_path / "nope.yaml"), "-o", str(tmp_path / "x.log")]) == 2
    assert "no such scenario file" in capsys.readouterr().err
    assert main(["simulate", str(EXAMPLE), "-o", str(tmp_path / "no" / "dir" / "x.log")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_help(capsys):
    with pytest.raises(SystemExit) as e:
        main(["simulate", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "--noise" in out and "--seed" in out and "examples:" in out


def test_simulators_are_registered_plugins():
    from fusion.api import Simulator
    from fusion.registry import default_registry
    reg = default_registry()
    names = set(reg.names("simulator"))
    assert {"imu", "range", "arrival_time", "gps", "magnetometer", "position"} <= names
    for name in names:
        cls = reg.get("simulator", name)
        assert issubclass(cls, Simulator) and cls.__doc__ and cls.Params.model_config.get("extra") == "forbid"


def test_a_scenario_error_and_a_config_error_are_formatted_alike(tmp_path, capsys):
    """One locator and one formatter (fusion.yamlsource): the same two mistakes (a value out of its bounds,
    an unknown key) in a scenario's sensor and in a config's sensor model give messages of one form,
    ``file:line: field.path: problem (and 1 more: file:line: field.path: unknown key)``."""
    import re

    scenario = tmp_path / "s.yaml"
    scenario.write_text("trajectory: {type: waypoints, waypoints: [[0, 0], [1, 0]]}\n"
                        "sensors:\n  u:\n    type: range\n    noise_sd: -1\n    bogus: 2\n")
    config = tmp_path / "c.yaml"
    config.write_text("name: c\nprocess: {type: pv, dims: 2, spectral_density: 0.1}\n"
                      "initial: {mean: {p: [0, 0], v: [0, 0]}, sd: {p: 1.0, v: 1.0}}\nfilter: ekf\n"
                      "sensors:\n  u:\n    model:\n      type: position\n      dim: 9\n      bogus: 2\n"
                      "    noise: {sd: 1}\n")
    assert main(["simulate", str(scenario), "-o", str(tmp_path / "x.log")]) == 2
    sim_err = capsys.readouterr().err.strip().splitlines()[-1]
    assert main(["validate", str(config)]) == 2
    cfg_err = capsys.readouterr().err.strip().splitlines()[-1]
    form = r"(\S+):(\d+): ([\w.]+): (Input should be [^(]+) \(and 1 more: (\S+):(\d+): ([\w.]+): unknown key\)$"
    sim, cfg = re.search(form, sim_err), re.search(form, cfg_err)
    assert sim and cfg, (sim_err, cfg_err)
    assert sim.group(1) == sim.group(5) == str(scenario) and cfg.group(1) == cfg.group(5) == str(config)
    assert (sim.group(2), sim.group(3), sim.group(6), sim.group(7)) == ("5", "sensors.u.noise_sd", "6",
                                                                         "sensors.u.bogus")
    assert (cfg.group(2), cfg.group(3), cfg.group(6), cfg.group(7)) == ("9", "sensors.u.model.dim", "10",
                                                                         "sensors.u.model.bogus")


def test_a_trajectory_too_long_to_hold_is_refused_before_sampling(tmp_path, capsys):
    """max_accel 1e-9 m/s^2 makes the example's route last 11.7 days: 2e7 lines, refused at once naming the
    cause (rather than memory growing to gigabytes without a word). In a subprocess with a timeout, so a
    regression fails instead of filling the machine."""
    import subprocess
    import sys

    import yaml

    d = yaml.safe_load(EXAMPLE.read_text())
    d["trajectory"]["max_accel"] = 1e-9
    sc = tmp_path / "tiny.yaml"
    sc.write_text(yaml.safe_dump(d))
    r = subprocess.run([sys.executable, "-m", "fusion.cli", "simulate", str(sc), "-o", str(tmp_path / "o.log")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "11.7 days from its waypoints, speed and max_accel 1e-09" in r.stderr
    assert "at most 1e+07 in one recording" in r.stderr and not (tmp_path / "o.log").exists()
