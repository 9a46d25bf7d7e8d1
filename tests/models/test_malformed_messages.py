"""A message a plugin cannot use is malformed, never an error that stops the run (issue 10 item 1).

Each case mutates one line of a shipped recording and runs ``fusion run`` through the CLI: exit 0, the
line counted as malformed for its sensor, and every other line used as in the unmutated run. The
plugins' own refusals (MalformedMessage with the reason) are checked directly too.
"""
import json
import textwrap
from pathlib import Path

import numpy as np
import pytest

from fusion.api import BuildContext, MalformedMessage, Message
from fusion.cli import main
from fusion.config import load_system

ROOT = Path(__file__).resolve().parents[2]
UWB = ROOT / "configs" / "uwb_pv_ukf.yaml"
ABPS = ROOT / "configs" / "abps_ins.yaml"


def run(tmp_path, config: Path, lines: list[str], name: str) -> dict:
    log, out = tmp_path / f"{name}.log", tmp_path / f"{name}.json"
    log.write_text("\n".join(lines) + "\n")
    assert main(["run", str(config), "--input", str(log), "-q", "--summary-json", str(out)]) == 0
    return json.loads(out.read_text())["sensors"]


def with_setting(tmp_path, config: Path, old: str, new: str) -> Path:
    text = config.read_text()
    assert old in text
    cfg = tmp_path / config.name
    cfg.write_text(text.replace(old, new).replace("../recordings/", str(ROOT / "recordings") + "/"))
    return cfg


# ----------------------------------------------------------------------------- range (uwb_pv_ukf)
UWB_LINES = (ROOT / "recordings" / "uwb_route1.log").read_text().splitlines()
UWB_AT = next(i for i, line in enumerate(UWB_LINES) if line.startswith("20.000000,uwb,"))  # "20.000000,uwb,B1,..."

RANGE_CASES = {
    "unknown beacon": "20.000000,uwb,B9,12.5",
    "number for beacon": "20.000000,uwb,3,12.5",
    "swapped fields": "20.000000,uwb,12.5,B1",
    "negative range": "20.000000,uwb,B1,-0.5",
    "nan range": "20.000000,uwb,B1,nan",
    "infinite range": "20.000000,uwb,B1,inf",
    "one field": "20.000000,uwb,B1",
    "three fields": "20.000000,uwb,B1,12.5,3.0",
    "label for range": "20.000000,uwb,B1,B2",
    "beyond max_range": "20.000000,uwb,B1,1e300",
    "beacon twice": "20.000000,uwb,B1,12.5,B1,12.6",
    "ten thousand pairs": "20.000000,uwb," + ",".join(["B1,12.5"] * 10_000),   # no 10,000 x 10,000 S
}


@pytest.fixture(scope="module")
def uwb_config(tmp_path_factory):
    # max_range: the hall is 30 m x 20 m; a PulsON 440 ranges far beyond it, but not a kilometre indoors
    return with_setting(tmp_path_factory.mktemp("cfg"), UWB, "model: range ", "model: {type: range, max_range: 1000} ")


@pytest.fixture(scope="module")
def uwb_base(uwb_config, tmp_path_factory):
    return run(tmp_path_factory.mktemp("base"), uwb_config, UWB_LINES, "base")


@pytest.mark.parametrize("case", list(RANGE_CASES))
def test_a_bad_range_line_is_malformed_and_the_run_goes_on(tmp_path, uwb_config, uwb_base, case):
    lines = list(UWB_LINES)
    lines[UWB_AT] = RANGE_CASES[case]
    got, base = run(tmp_path, uwb_config, lines, "m")["uwb"], uwb_base["uwb"]
    assert got["malformed"] == base["malformed"] + 1
    assert got["used"] == base["used"] - 1 and got["rejected"] == base["rejected"]


def test_range_beyond_max_range_says_so(tmp_path, uwb_config, capsys):
    lines = list(UWB_LINES)
    lines[UWB_AT] = RANGE_CASES["beyond max_range"]
    log = tmp_path / "m.log"
    log.write_text("\n".join(lines) + "\n")
    assert main(["run", str(uwb_config), "--input", str(log)]) == 0
    err = capsys.readouterr().err
    assert f"malformed: t=20.000 s uwb: line {UWB_AT + 1}: range 1e+300 m beyond max_range 1000.0 m" in err


def test_range_reasons_name_what_is_valid():
    system = load_system(UWB)
    model = system.sensors["uwb"].model
    for values, reason in [(("B9", 1.0), "unknown beacon 'B9' (known: B1, B2, B3, B4)"),
                           ((3.0, 1.0), "expects a beacon name, got 3.0"),
                           (("B1",), "'beacon range' pairs, got 1 value(s)"),
                           (("B1", float("nan")), "non-finite range"),
                           (("B1", -1.0), "negative range -1.0 m"),
                           (("B1", 1.0, "B2", 2.0, "B1", 3.0), "beacon 'B1' twice in one message"),
                           (("B1", (1.0, 2.0)), "range expects numbers, got ((1.0, 2.0),)")]:
        with pytest.raises(MalformedMessage, match=reason.replace("(", r"\(").replace(")", r"\)")):
            model.observe(Message(1.0, "uwb", values))


# ----------------------------------------------------------------------------- ols_trilateration (abps_ins)
ABPS_LINES = [line for line in (ROOT / "recordings" / "abps_mine.log").read_text().splitlines()
              if line.startswith("#") or float(line.split(",", 1)[0]) < 30.0]
ABPS_AT = next(i for i, line in enumerate(ABPS_LINES) if ",abps," in line and float(line.split(",")[0]) > 20.0)
_T = ABPS_LINES[ABPS_AT].split(",")[0]

OLS_CASES = {
    "unknown beacon": f"{_T},abps,B9,2.5",
    "number for beacon": f"{_T},abps,9,2.5",
    "swapped fields": f"{_T},abps,2.5,B3",
    "negative range": f"{_T},abps,B3,-2.5",
    "beyond max_range": f"{_T},abps,B3,1e20",
    "label for range": f"{_T},abps,B3,B4",
    "three fields": f"{_T},abps,B3,2.5,1.0",
    "beacon twice": f"{_T},abps,B3,2.5,B3,2.6",
}
BY_HEADER = ("three fields", "beacon twice")   # more values than '# fields abps beacon range' names


@pytest.fixture(scope="module")
def abps_config(tmp_path_factory):
    return with_setting(tmp_path_factory.mktemp("cfg"), ABPS, "range_sd: 0.05 ",
                        "max_range: 100\n      range_sd: 0.05 ")


@pytest.fixture(scope="module")
def abps_base(abps_config, tmp_path_factory):
    return run(tmp_path_factory.mktemp("base"), abps_config, ABPS_LINES, "base")


@pytest.mark.parametrize("case", [c for c in OLS_CASES if c not in BY_HEADER])
def test_a_bad_abps_range_is_malformed_and_the_run_goes_on(tmp_path, abps_config, abps_base, case):
    lines = list(ABPS_LINES)
    lines[ABPS_AT] = OLS_CASES[case]
    got = run(tmp_path, abps_config, lines, "m")
    assert got["abps"]["malformed"] == abps_base["abps"]["malformed"] + 1
    assert got["imu"]["used"] == abps_base["imu"]["used"]
    # the cycle that lost a range still has six beacons: as many fixes as before
    assert got["abps"]["used"] == abps_base["abps"]["used"]


@pytest.mark.parametrize("case", BY_HEADER)
def test_extra_fields_are_malformed_by_the_header(tmp_path, abps_config, abps_base, case):
    """'# fields abps beacon range' names two values: the parser refuses more before any plugin."""
    lines = list(ABPS_LINES)
    lines[ABPS_AT] = OLS_CASES[case]
    got = run(tmp_path, abps_config, lines, "m")
    assert got["abps"]["malformed"] == abps_base["abps"]["malformed"] + 1
    assert got["imu"]["used"] == abps_base["imu"]["used"]


@pytest.mark.parametrize("case", [c for c in OLS_CASES if c != "three fields"])
def test_ols_feed_refuses_with_the_reason(abps_config, case):
    solver = load_system(abps_config).sensors["abps"].preprocessor
    t, _, *values = OLS_CASES[case].split(",")
    vals = tuple(v if v[:1].isalpha() else float(v) for v in values)
    reason = {"unknown beacon": "unknown beacon 'B9'", "number for beacon": "unknown beacon 9.0",
              "swapped fields": "unknown beacon 2.5", "negative range": "must be finite and >= 0, got -2.5",
              "beyond max_range": "beyond max_range 100.0 m", "label for range": "not a number: 'B4'",
              "beacon twice": "beacon named twice in one message"}[case]
    with pytest.raises(MalformedMessage, match=reason.replace("(", r"\(")):
        solver.feed(Message(float(t), "abps", vals, 7))
    assert solver.flush() == []   # nothing of the refused message was gathered


def test_ols_ranges_too_long_for_float64_are_malformed_or_give_no_fix():
    from fusion_plugins.solvers.ols_trilateration import OlsTrilateration

    beacons = {"B1": np.array([0.0, 0.0, 0.0]), "B2": np.array([10.0, 0.0, 0.0]), "B3": np.array([0.0, 10.0, 0.0])}
    solver = OlsTrilateration(OlsTrilateration.Params(refine_iterations=3), BuildContext(beacons=beacons))
    with pytest.raises(MalformedMessage, match=r"range to B1 1e\+200 m beyond 1e\+150 \(its square overflows"):
        solver.feed(Message(0.0, "abps", ("B1", 1e200)))
    out = []
    for i, b in enumerate(beacons):   # squares just representable: a fix, or no fix, never an exception
        out += solver.feed(Message(0.1 * i, "abps", (b, 1e149 * (1 + i))))
    out += solver.flush()                     # the firing schedule holds ranges while it learns the period
    assert all(np.all(np.isfinite(m.values)) for m in out)
    from fusion_plugins.solvers.ols_trilateration import REASONS

    c = solver.counters
    assert c["cycles"] >= 1 and c["fixes"] + sum(c[r] for r in REASONS) == c["cycles"]


# ----------------------------------------------------------------------------- position and the line decoder
FIX_CONFIG = """\
name: fixes
beacons: {}
process: {type: pv, dims: 2, spectral_density: 0.5}
initial: {mean: {p: [0, 0], v: [0, 0]}, sd: {p: 5.0, v: 1.0}}
filter: ekf
sensors:
  fix:
    decoder: {type: line, numeric: true}
    model: position
    noise: {sd: 0.5}
"""


def fix_lines(n=40):
    rng = np.random.default_rng(0)
    lines = ["# fields truth px py vx vy"]
    for k in range(n):
        t = 0.5 * k
        x, y = 1.0 * t, 0.5 * t
        lines.append(f"{t:.3f},truth,{x},{y},1.0,0.5")
        ex, ey = rng.normal(0, 0.5, 2)
        lines.append(f"{t:.3f},fix,{x + ex:.4f},{y + ey:.4f},0,0.25,0,0,0.25,0,1")
    return lines


POSITION_CASES = {
    "covariance not positive definite": "10.000,fix,10.0,5.0,0,0.25,1.0,0,0.25,0,1",
    "zero covariance": "10.000,fix,10.0,5.0,0,0,0,0,0,0,0",
    "negative variance": "10.000,fix,10.0,5.0,0,-0.25,0,0,0.25,0,1",
    "negative age": "10.000,fix,10.0,5.0,0,0.25,0,0,0.25,0,1,-0.5",
    "label among numbers": "10.000,fix,10.0,B1,0,0.25,0,0,0.25,0,1",
    "four values": "10.000,fix,10.0,5.0,0,1",
}


@pytest.mark.parametrize("case", list(POSITION_CASES))
def test_a_bad_fix_is_malformed_and_the_run_goes_on(tmp_path, case):
    cfg = tmp_path / "fixes.yaml"
    cfg.write_text(FIX_CONFIG)
    lines = fix_lines()
    base = run(tmp_path, cfg, lines, "base")["fix"]
    at = lines.index(next(line for line in lines if line.startswith("10.000,fix,")))
    lines[at] = POSITION_CASES[case]
    got = run(tmp_path, cfg, lines, "m")["fix"]
    assert got["malformed"] == base["malformed"] + 1 and got["used"] == base["used"] - 1


def test_position_reasons():
    from fusion_plugins.measurement.position import Position

    system = load_system_text(FIX_CONFIG)
    model = system.sensors["fix"].model
    assert isinstance(model, Position)
    with pytest.raises(MalformedMessage, match=r"covariance \[\[0.25, 1.0\], \[1.0, 0.25\]\] \(m\^2\) is not positive"):
        model.observe(Message(1.0, "fix", (1.0, 2.0, 0.0, 0.25, 1.0, 0.0, 0.25, 0.0, 1.0)))
    with pytest.raises(MalformedMessage, match="expects 2 coordinates"):
        model.observe(Message(1.0, "fix", (1.0, 2.0, 0.0, 1.0)))
    decoder = system.sensors["fix"].decoder
    with pytest.raises(MalformedMessage, match="value 2: expected a finite number, got 'B1'"):
        decoder.decode(Message(1.0, "fix", (1.0, "B1")))


def load_system_text(text):
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "c.yaml"
        p.write_text(textwrap.dedent(text))
        return load_system(p)
