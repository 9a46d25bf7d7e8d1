"""Config values a run cannot use are exit-2 errors of ``fusion validate`` with file:line and field
(issue 10 item 3): non-finite floats, absurd initial sds and output rates, nesting and alias bombs,
duplicate keys, sd with R, beacons a recording needs, bad --filter-param values."""
from pathlib import Path

import pytest

from fusion.cli import main

ROOT = Path(__file__).resolve().parents[2]
ABPS = (ROOT / "configs" / "abps_ins.yaml").read_text().replace("../recordings/", f"{ROOT}/recordings/")
UWB = (ROOT / "configs" / "uwb_pv_ukf.yaml").read_text().replace("../recordings/", f"{ROOT}/recordings/")


def validate(tmp_path, capsys, text: str) -> tuple[int, str, Path]:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(text)
    code = main(["validate", str(cfg)])
    return code, capsys.readouterr().err.strip(), cfg


def line_of(text: str, needle: str) -> int:
    return next(i for i, line in enumerate(text.splitlines(), 1) if needle in line)


def edit(text: str, old: str, new: str) -> str:
    assert text.count(old) == 1, old
    return text.replace(old, new)


NON_FINITE = [  # (config, old, new, field path in the message, key whose line is named)
    (UWB, "spectral_density: 0.2", "spectral_density: .nan", "process.spectral_density", "spectral_density:"),
    (UWB, "noise: {sd: 0.1}", "noise: {sd: .inf}", "sensors.uwb.noise.sd", "noise: {sd"),
    (UWB, "noise: {sd: 0.1}", "noise: {R: [[.nan]]}", "sensors.uwb.noise.R.0.0", "noise: {R"),
    (UWB, "noise: {sd: 0.1}", "noise: -.inf", "sensors.uwb.noise", "noise: -.inf"),
    (UWB, "mean: {p: [3.0, 3.0]", "mean: {p: [3.0, .nan]", "initial.mean.p.1", "mean: {p"),
    (UWB, "sd: {p: 1.0, v: 0.5}", "sd: {p: .inf, v: 0.5}", "initial.sd.p", "sd: {p"),
    (UWB, "  B2: [30.0, 0.0]", "  B2: [30.0, .inf]", "beacons.B2.1", "B2:"),
    (UWB, "alpha: 0.5", "alpha: .nan", "filter.alpha", "alpha:"),
    (UWB, "max_latency: 0.0", "max_latency: .inf", "scheduler.max_latency", "max_latency:"),
    (UWB, "probability: 0.9999", "probability: .nan", "sensors.uwb.gate.probability", "probability:"),
    (UWB, "    role: measurement", "    role: measurement\n    time_offset: .inf", "sensors.uwb.time_offset", "time_offset:"),
    (UWB, "    role: measurement", "    role: measurement\n    time_offset: nan", "sensors.uwb.time_offset", "time_offset:"),
    (ABPS, "type: position, lever_arm: [0.2, 0.0, -0.4]", "type: position, lever_arm: [0.2, .nan, -0.4]",
     "sensors.abps.model.lever_arm.1", "type: position, lever_arm"),
    (ABPS, "accel_noise_density: 2.0e-3", "accel_noise_density: .inf", "process.accel_noise_density", "accel_noise_density:"),
    (ABPS, "gyro_bias_rw: 1.2e-5", "gyro_bias_rw: [1.0e-5, .nan, 1.0e-5]", "process.gyro_bias_rw.1", "gyro_bias_rw:"),
    (ABPS, "      z: -0.75", "      z: .nan", "sensors.abps.preprocessor.z", "z: .nan"),
    (ABPS, "      z_sd: 0.05", "      z_sd: .inf", "sensors.abps.preprocessor.z_sd", "z_sd:"),
    (ABPS, "gravity: 9.80665", "gravity: .inf", "process.gravity", "gravity:"),
]


@pytest.mark.parametrize("text,old,new,field,key", NON_FINITE, ids=[f"{c[3]}={c[2].split(':')[-1].strip()}" for c in NON_FINITE])
def test_non_finite_values_are_refused_with_file_line_field(tmp_path, capsys, text, old, new, field, key):
    bad = edit(text, old, new)
    code, err, cfg = validate(tmp_path, capsys, bad)
    assert code == 2 and len(err.splitlines()) == 1
    assert err.startswith(f"{cfg}:{line_of(bad, key)}: {field}: Input should be a finite number"), err


@pytest.mark.parametrize("old,new,expect,key", [
    ("sd: {p: 1.0, v: 0.5}", "sd: {p: 1.0e+200, v: 0.5}", "initial.sd.p: 1e+200 is above 1e+06", "sd: {p"),
    ("sd: {p: 1.0, v: 0.5}", "sd: {p: 1.0, v: 2.0e+6}", "initial.sd.v: 2e+06 is above 1e+06", "sd: {p"),
    ("sd: {p: 1.0, v: 0.5}", "P: [[1.0e+13, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]",
     "initial.P: variance 1e+13 of px above 1e+12", "P: [["),
    ("sd: {p: 1.0, v: 0.5}", "sd: {p: 1.0e-200, v: 0.5}", "initial.sd: standard deviations below 1e-150 square to a zero",
     "sd: {p"),
    ("noise: {sd: 0.1}", "noise: {sd: 1.0e+200}", "sensors.uwb.noise.sd: [1e+200] squared is not a positive finite",
     "noise:"),
    ("noise: {sd: 0.1}", "noise: {R: [[1.0e+308]]}", None, None),   # finite and positive definite: fine
    ("on_update: true ", "on_update: true\n  rate_hz: 1.0e+9 ", "output.rate_hz: Input should be less than or equal "
     "to 1000", "rate_hz:"),
    ("on_update: true ", "on_update: false ", "output: Value error, on_update: false and no rate_hz: the run would "
     "emit no estimate", "output:"),   # not ok from validate and a run that never initialises
    ("late_policy: drop", "late_policy: drop\n  history: 1000000000", "scheduler.history: Input should be less than "
     "or equal to 100000", "history:"),
    ("noise: {sd: 0.1}", "noise: {sd: 0.1, R: [[0.01]]}", "sensors.uwb.noise: Value error, give sd or R, not both",
     "noise:"),
    ("sd: {p: 1.0, v: 0.5}", "sd: {p: 1.0, v: 0.5}\n  P: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]",
     "initial: Value error, give sd or P, not both", "initial:"),   # sd is not silently ignored
    ("noise: {sd: 0.1}", "noise: {R: [[1, 0.5], [0.5, 1]]}", "sensors.uwb.noise.R: must be 1 x 1", "noise:"),
    ("noise: {sd: 0.1}", "noise: {R: [[1, 2], [3]]}", "sensors.uwb.noise.R: rows of different lengths [1, 2]", "noise:"),
    ("sd: {p: 1.0, v: 0.5}", "P: [[1, 0, 0, 0], [0, 1, 0], [0, 0, 1, 0], [0, 0, 0, 1]]",
     "initial.P: rows of different lengths [3, 4]", "P: [["),
    ("model: range ", "model: {type: range, max_range: -1} ", "sensors.uwb.model.max_range: Input should be greater "
     "than 0", "model: {"),
])
def test_absurd_values_are_refused(tmp_path, capsys, old, new, expect, key):
    bad = edit(UWB, old, new)
    code, err, cfg = validate(tmp_path, capsys, bad)
    if expect is None:
        assert code == 0, err
        return
    assert code == 2 and len(err.splitlines()) == 1, err
    assert err.startswith(f"{cfg}:{line_of(bad, key)}: {expect}"), err
    assert "(and " not in err   # one problem, not the members of a union that do not fit


@pytest.mark.parametrize("text,old,new,expect", [
    (UWB, "alpha: 0.5", "alpha: 1.0e-300", "filter: filter 'ukf': unscented transform needs alpha^2 (n + kappa) > 0"),
    (UWB, "kappa: 0.0", "kappa: -1.0e+300", "filter: filter 'ukf': unscented transform needs alpha^2 (n + kappa) > 0"),
    (UWB, "kappa: 0.0", "kappa: 1.0e+300", "sigma points at sqrt(alpha^2 (n + kappa)) = 5e+149 standard deviations"),
    (UWB, "beta: 2.0", "beta: -1.0e+300", "zeroth sigma-point weight 1e+300"),
    (ABPS, "alpha: 0.5 ", "alpha: 1.0e-6 ", "filter: filter 'srukf': zeroth sigma-point weight 1e+12"),
    (ABPS, "range_sd: 0.05 ", "range_sd: 1.0e+300 ", "sensors.abps.preprocessor.range_sd: Input should be less than or "
     "equal to 1000000"),
    (UWB, "    role: measurement", "    role: measurement\n    time_offset: 1.0e+300", "sensors.uwb.time_offset: Input "
     "should be less than or equal to 10000000000"),
])
def test_values_a_run_could_not_survive_are_refused(tmp_path, capsys, text, old, new, expect):
    """Each of these passed validate and ended the run with exit 1 (found by scanning every number of the
    shipped configs through 1e300, 1e-300, -1e300)."""
    code, err, cfg = validate(tmp_path, capsys, edit(text, old, new))
    assert code == 2 and len(err.splitlines()) == 1 and err.startswith(str(cfg)) and expect in err, err


def test_a_range_sensor_without_noise_is_refused(tmp_path, capsys):
    """A range carries no covariance: without noise the run could use none of them."""
    bad = edit(UWB, "    noise: {sd: 0.1}          # m\n", "")
    code, err, cfg = validate(tmp_path, capsys, bad)
    assert code == 2 and err.startswith(f"{cfg}:{line_of(bad, '  uwb:')}: sensors.uwb: a measurement sensor needs "
                                        "'noise:' (sd or R): its model 'range' takes no covariance")


def test_a_position_fed_by_a_solver_needs_no_noise(tmp_path, capsys):
    code, err, _ = validate(tmp_path, capsys, ABPS)   # abps: fixes carry their covariance
    assert code == 0, err
    bad = edit(ABPS, "model: {type: position, ", "model: {type: position, use_fix_covariance: false, ")
    code, err, _ = validate(tmp_path, capsys, bad)
    assert code == 2 and "a measurement sensor needs 'noise:'" in err


def test_a_recording_that_is_a_directory_is_named_at_its_line(tmp_path, capsys):
    bad = edit(UWB, f"recording: {ROOT}/recordings/uwb_route1.log", f"recording: {ROOT}")
    code, err, cfg = validate(tmp_path, capsys, bad)
    assert code == 2 and err.startswith(f"{cfg}:{line_of(bad, 'recording:')}: recording: {ROOT}: is a directory")


def test_a_zero_quaternion_is_refused(tmp_path, capsys):
    bad = edit(ABPS, "q: [1, 0, 0, 0]", "q: [0, 0, 0, 0]")
    code, err, cfg = validate(tmp_path, capsys, bad)
    assert code == 2 and f"{cfg}:{line_of(bad, 'mean: {p')}: initial.mean.q: a quaternion needs a non-zero norm" in err


def test_ols_needing_more_beacons_than_defined_is_refused(tmp_path, capsys):
    bad = edit(ABPS, "      dim: 2 ", "      min_beacons: 9\n      dim: 2 ")
    code, err, _ = validate(tmp_path, capsys, bad)
    assert code == 2 and "min_beacons 9 but only 7 beacon(s)" in err


def test_a_beacon_the_recording_declares_but_the_config_lacks(tmp_path, capsys):
    bad = edit(ABPS, "  B5: [20.0, 0.1, -0.9]\n", "")
    code, err, cfg = validate(tmp_path, capsys, bad)
    assert code == 2 and len(err.splitlines()) == 1
    assert err.startswith(f"{cfg}:{line_of(bad, 'beacons:')}: beacons: the recording abps_mine.log declares "
                          "beacon(s) the config does not define (B5: [20.0, 0.1, -0.9])"), err


@pytest.mark.parametrize("text,expect", [
    ("name: x\nbeacons: " + "[" * 10_000 + "]" * 10_000 + "\n", ":2: invalid YAML: nested deeper than 64 levels"),
    ("name: x\nbeacons: " + "{a: " * 10_000 + "1" + "}" * 10_000 + "\n", ":2: invalid YAML: nested deeper than 64 levels"),
    ("name: x\nbeacons: " + "[{a: " * 5_000 + "1" + "}]" * 5_000 + "\n", ":2: invalid YAML: nested deeper than 64 levels"),
    ("name: x\na: &a [*a]\n", ":2: invalid YAML: recursive alias"),
    ("name: x\n" + "".join(f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 10) if i else '1, 2, 3, 4, 5, 6, 7, 8, 9'}]\n"
                           for i in range(9)), "invalid YAML: expands to more than 100000 values"),
])
def test_yaml_bombs_are_one_line_errors(tmp_path, capsys, text, expect):
    code, err, cfg = validate(tmp_path, capsys, text)
    assert code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err
    assert err.startswith(str(cfg)) and expect in err, err


@pytest.mark.parametrize("old,new,dup,first", [
    ("  B2: [30.0, 0.0]\n", "  B2: [30.0, 0.0]\n  B1: [5.0, 5.0]\n", "B1", "B1:"),
    ("sd: {p: 1.0, v: 0.5}", "sd: {p: 1.0, v: 0.5, p: 2.0}", "p", "sd: {p"),
    ("name: uwb_pv_ukf\n", "name: uwb_pv_ukf\nname: other\n", "name", "name: uwb"),
])
def test_duplicate_keys_are_errors_with_both_lines(tmp_path, capsys, old, new, dup, first):
    bad = edit(UWB, old, new)
    code, err, cfg = validate(tmp_path, capsys, bad)
    lines = bad.splitlines()
    second = max(i for i, line in enumerate(lines, 1) if f"{dup}:" in line.split("#")[0] and line.count(f"{dup}:") and
                 (i != line_of(bad, first) or line.count(f"{dup}:") > 1))
    assert code == 2 and len(err.splitlines()) == 1
    assert err == f"{cfg}:{second}: invalid YAML: duplicate key {dup!r} (first at line {line_of(bad, first)}; a later " \
                  "one would silently replace it)"


def test_merge_keys_still_override(tmp_path, capsys):
    """A key after a YAML merge (<<) replaces the merged one by design: not a duplicate."""
    text = edit(UWB, "initial:\n", "sds: &d {p: 9.0, v: 0.5}\ninitial:\n")
    text = edit(text, "sd: {p: 1.0, v: 0.5}", "sd: {<<: *d, p: 1.0}")
    from fusion.yamlsource import parse_yaml

    data, _ = parse_yaml(text)
    assert data["initial"]["sd"] == {"p": 1.0, "v": 0.5}


@pytest.mark.parametrize("param,expect", [
    ("alpha=[1", "--filter-param 'alpha=[1': VALUE is not valid YAML (expected ',' or ']', but got '<stream end>')"),
    ("alpha", "--filter-param 'alpha': expected KEY=VALUE"),
    ("alpha=" + "[" * 10_000, "VALUE is not valid YAML (nested deeper than 64 levels)"),
    ("alpha=.nan", "filter (--filter/--filter-param): alpha: Input should be a finite number"),
    ("alpha={a: 1, a: 2}", "VALUE is not valid YAML (duplicate key 'a'"),
])
def test_bad_filter_param_is_one_line_exit_2(capsys, param, expect):
    assert main(["run", str(ROOT / "configs" / "example_2d.yaml"), "-q", "--filter-param", param]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expect in err and len(err) < 300, err


def test_filter_param_still_sets_yaml_values(tmp_path):
    import json

    out = tmp_path / "s.json"
    assert main(["run", str(ROOT / "configs" / "example_2d.yaml"), "-q", "--filter-param", "alpha=0.3",
                 "--filter-param", "linear_prediction=never", "--summary-json", str(out)]) == 0
    assert json.loads(out.read_text())["filter"] == "ukf"


@pytest.mark.parametrize("old,new,expect", [
    ("  speed: 1.3 ", "  speed: .nan ", "Input should be a finite number"),
    ("  B2: [20.0, 0.0]", "  B2: [20.0, .inf]", "Input should be a finite number"),
    ("  speed: 1.3 ", "  speed: 1.3\n  speed: 2.0 ", "duplicate key 'speed'"),
    ("seed: 1\n", "seed: 1\nx: " + "[" * 10_000 + "]" * 10_000 + "\n", "nested deeper than 64 levels"),
])
def test_scenarios_have_the_same_limits(tmp_path, capsys, old, new, expect):
    scenario = tmp_path / "s.yaml"
    scenario.write_text(edit((ROOT / "scenarios" / "example_2d.yaml").read_text(), old, new))
    assert main(["simulate", str(scenario), "-o", str(tmp_path / "x.log")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expect in err and "Traceback" not in err, err


@pytest.mark.parametrize("old,new,expect", [
    ("  uwb:\n", "  'my uwb':\n", "'my uwb' can never name a log line's sensor"),
    ("  uwb:\n", "  truth:\n", "'truth' lines are never fed to the filter"),
])
def test_sensor_names_a_log_can_carry(tmp_path, capsys, old, new, expect):
    bad = edit(UWB, old, new)
    code, err, cfg = validate(tmp_path, capsys, bad)
    assert code == 2 and err.startswith(f"{cfg}:{line_of(bad, new.strip())}: sensors.") and expect in err, err


@pytest.mark.parametrize("name", ["'B 1'", "'1'", "nan", "'-B1'"])
def test_beacon_names_a_log_can_carry(tmp_path, capsys, name):
    bad = edit(UWB, "  B2: [30.0, 0.0]", f"  {name}: [30.0, 0.0]")
    code, err, cfg = validate(tmp_path, capsys, bad)
    assert code == 2 and err.startswith(f"{cfg}:{line_of(bad, 'beacons:')}: beacons: Value error, beacon") and \
        "can never be named by a log line" in err, err


def test_the_initial_fix_comes_from_a_measurement_sensor(tmp_path, capsys):
    bad = edit(ABPS, "from_sensor: abps", "from_sensor: imu")
    code, err, cfg = validate(tmp_path, capsys, bad)
    assert code == 2 and f"{cfg}:{line_of(bad, 'from_sensor')}: initial.from_sensor: sensor 'imu' is an input" in err
