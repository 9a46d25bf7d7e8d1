"""What a plugin hands the run on a message is checked where the scheduler receives it, so a plugin's bug
loses that message (docs/pipeline.md "Ctrl-C, and a source that fails": a component that fails on a message
only loses that message): counted malformed for its sensor, one event naming the component and what (and the
count at the end), the run going on with the other sensors. A model's ``observe`` returning an unusable
Observation (a NaN time, z or R of the wrong shape, an R that is negative, NaN or not symmetric), a gate whose
``check`` raises or returns something else than ``(GateDecision, state)``, a decoder returning something else
than a Message (each named, not an internal error, exit 1, nor a silent "rejected")."""
import textwrap

import numpy as np
import pytest
from pydantic import Field

import fusion.registry
from fusion import pipeline
from fusion.api import Decoder, Gate, GateDecision, MeasurementModel, Observation, Params
from fusion.cli import main
from fusion.config import load_system
from fusion.registry import make_plugin_manager

BEACONS = {"B1": [0.0, 0.0], "B2": [30.0, 0.0], "B3": [30.0, 20.0], "B4": [0.0, 20.0]}

OBSERVE_FAULTS = {   # fault -> what the event says
    "t_nan": "its time t = nan is not finite (s)",
    "t_text": "its time t = '1.0' is not",
    "z_shape": "its z has shape (2,), expected (1,) (its model's dim)",
    "z_nan": "its z = [nan] is not finite",
    "R_shape": "its R has shape (2, 2), expected (1, 1)",
    "R_1d": "its R has shape (1,), expected (1, 1)",
    "R_negative": "its R = [[-25.0]] is not a positive finite variance",
    "R_nan": "its R = [[nan]] is not a positive finite variance",
    "not_observation": "it is (0.1, array([3.])) (tuple), not a fusion.api.Observation (or None)",
}


class HeightParams(Params):
    fault: str = Field("none", description="which bad Observation observe returns (test)")


class Height(MeasurementModel[HeightParams]):
    """Height (m): the state's p_y."""

    name = "test_height"
    Params = HeightParams
    dim = 1

    def h(self, x):
        return np.asarray(x)[..., 1:2]

    def jacobian(self, x):
        H = np.zeros((1, len(x)))
        H[0, 1] = 1.0
        return H

    def observe(self, message):
        z = message.floats()
        fault = self.params.fault
        t = {"t_nan": float("nan"), "t_text": "1.0"}.get(fault, message.t)
        z = {"z_shape": np.r_[z, z], "z_nan": z * np.nan}.get(fault, z)
        R = {"R_shape": np.eye(2), "R_1d": np.array([25.0]), "R_negative": np.array([[-25.0]]),
             "R_nan": np.array([[np.nan]]), "list": [[0.01]]}.get(fault)
        if fault == "not_observation":
            return (message.t, z)
        if fault == "list":   # lists where arrays belong work as before (taken as float arrays)
            return Observation(t, z.tolist(), self, R)
        return Observation(t, z, self, R)


class PlaneParams(Params):
    fault: str = Field("none", description="none|asymmetric|indefinite (test)")


class Plane(MeasurementModel[PlaneParams]):
    """Position (m): the state's p, with a covariance of the message's own."""

    name = "test_plane"
    Params = PlaneParams
    dim = 2
    carries_R = True

    def h(self, x):
        return np.asarray(x)[..., 0:2]

    def observe(self, message):
        R = {"asymmetric": [[0.01, 0.005], [0.0, 0.01]], "indefinite": [[0.01, 0.02], [0.02, 0.01]]}.get(
            self.params.fault, [[0.01, 0.0], [0.0, 0.01]])
        return Observation(message.t, message.floats(), self, np.array(R))


class FaultyGateParams(Params):
    fault: str = Field("none", description="none|raise|bool|reasons (test)")


class FaultyGate(Gate):
    """NIS gate at 9 (dimensionless), with a fault to order."""

    name = "test_gate"
    Params = FaultyGateParams

    def check(self, nis, dim, state):
        fault = self.params.fault
        if fault == "raise":
            raise RuntimeError("gate boom")
        if fault == "bool":
            return True
        if fault == "reasons":
            return GateDecision(True, 9.0, None), state
        return GateDecision(nis <= 9.0, 9.0), state


class ListDecoder(Decoder):
    """Returns the message's values as a list instead of a Message (a plugin's bug)."""

    name = "test_list_decoder"

    def decode(self, message):
        return message.floats().tolist()


@pytest.fixture
def registry(monkeypatch):
    _, reg = make_plugin_manager()
    for cls in (Height, Plane, FaultyGate, ListDecoder):
        reg.add(cls)
    monkeypatch.setattr(fusion.registry, "_DEFAULT", reg)
    return reg


def config(tmp_path, sensor="{model: {type: test_height, fault: none}, noise: {sd: 0.1}}"):
    path = tmp_path / "c.yaml"
    path.write_text(textwrap.dedent(f"""\
        name: returns
        recording: {tmp_path / 'r.log'}
        beacons: {BEACONS}
        process: {{type: pv, dims: 2, spectral_density: 0.05}}
        initial: {{mean: {{p: [3.0, 3.0], v: [0.0, 0.0]}}, sd: {{p: 1.0, v: 0.5}}}}
        filter: ekf
        sensors:
          uwb: {{model: range, noise: {{sd: 0.1}}}}
          alt: {sensor}
        output: {{on_update: true}}
        """))
    lines = ["# fields uwb beacon range", "# fields truth px py vx vy"]
    for k in range(200):
        t = 0.05 * k
        p = np.array([3.0 + 0.5 * t, 3.0])
        b = list(BEACONS)[k % 4]
        lines.append(f"{t:.6f},uwb,{b},{np.linalg.norm(p - BEACONS[b]):.6f}")
        lines.append(f"{t:.6f},truth,{p[0]:.6f},{p[1]:.6f},0.5,0.0")
        if k % 5 == 2:
            lines.append(f"{t:.6f},alt,{p[0]:.6f},{p[1]:.6f}" if "plane" in sensor else f"{t:.6f},alt,{p[1]:.6f}")
    (tmp_path / "r.log").write_text("\n".join(lines) + "\n")
    return path


def run(tmp_path, sensor):
    events = []
    result = pipeline.run(load_system(config(tmp_path, sensor)), tmp_path / "r.log", on_event=events.append)
    return result.summary, [e for e in events if e.sensor == "alt"]


def assert_lost(summary, told, *texts, count=40, per_message=False):
    """Every alt message lost (malformed), the run gone on with uwb, the component and what named."""
    alt = summary["sensors"]["alt"]
    assert alt["received"] == alt["malformed"] == count and alt["used"] == alt["rejected"] == 0, alt
    assert summary["sensors"]["uwb"]["used"] == 200 and summary["errors"]["position_rmse_m"] < 0.2
    if not per_message:
        assert [e.kind for e in told] == ["malformed", "warning"], [e.detail for e in told]  # the first, the count
        assert f"{count} times" in told[1].detail
    for text in texts:
        assert text in told[0].detail, (text, told[0].detail)


@pytest.mark.parametrize("fault", list(OBSERVE_FAULTS))
def test_an_unusable_observation_loses_only_its_message(registry, tmp_path, fault):
    summary, told = run(tmp_path, f"{{model: {{type: test_height, fault: {fault}}}, noise: {{sd: 0.1}}}}")
    assert_lost(summary, told, "measurement model 'test_height' returned an unusable Observation",
                OBSERVE_FAULTS[fault], "line ")


@pytest.mark.parametrize("fault,what", [("asymmetric", "its R is not symmetric"),
                                        ("indefinite", "its R is not positive definite")])
def test_an_observation_whose_R_is_no_covariance_loses_only_its_message(registry, tmp_path, fault, what):
    summary, told = run(tmp_path, f"{{model: {{type: test_plane, fault: {fault}}}}}")
    assert_lost(summary, told, "measurement model 'test_plane'", what)


def test_a_usable_observation_is_used_lists_included(registry, tmp_path):
    for sensor in ("{model: {type: test_height, fault: none}, noise: {sd: 0.1}}",
                   "{model: {type: test_height, fault: list}, noise: {sd: 0.1}}",
                   "{model: {type: test_plane, fault: none}}"):
        summary, told = run(tmp_path, sensor)
        assert summary["sensors"]["alt"]["used"] == 40 and not told, (sensor, [e.detail for e in told])


@pytest.mark.parametrize("fault,what", [("raise", "RuntimeError: gate boom"),
                                        ("bool", "check returned True (bool), expected (GateDecision, next state)"),
                                        ("reasons", "expected accepted a bool and reasons a tuple")])
def test_a_gate_that_fails_loses_only_its_message(registry, tmp_path, fault, what):
    summary, told = run(tmp_path, f"{{model: test_height, noise: {{sd: 0.1}}, gate: {{type: test_gate, fault: {fault}}}}}")
    assert_lost(summary, told, "gate 'test_gate' failed in the update", what)


def test_a_working_gate_is_unchanged(registry, tmp_path):
    summary, told = run(tmp_path, "{model: test_height, noise: {sd: 0.1}, gate: {type: test_gate}}")
    assert summary["sensors"]["alt"]["used"] == 40 and not told


def test_a_decoder_that_returns_no_message_loses_each_message(registry, tmp_path):
    summary, told = run(tmp_path, "{model: test_height, decoder: test_list_decoder, noise: {sd: 0.1}}")
    assert_lost(summary, told, "decoder 'test_list_decoder' returned [3.0] (list), expected a fusion.api.Message "
                "or None", per_message=True)


def test_fusion_run_with_a_failing_gate_exits_0_and_writes_the_summary(registry, tmp_path, capsys):
    cfg = config(tmp_path, "{model: test_height, noise: {sd: 0.1}, gate: {type: test_gate, fault: raise}}")
    assert main(["run", str(cfg), "-q", "--summary-json", str(tmp_path / "s.json")]) == 0
    assert "internal error" not in capsys.readouterr().err
    assert (tmp_path / "s.json").exists()


def test_a_run_whose_every_message_was_lost_says_so(registry, tmp_path):
    """Not "no input reached the filter": the input came, a plugin failed on all of it (the events say how)."""
    cfg = config(tmp_path, "{model: {type: test_height, fault: R_nan}, noise: {sd: 0.1}}")
    cfg.write_text(cfg.read_text().replace("  uwb: {model: range, noise: {sd: 0.1}}\n", ""))
    log = tmp_path / "r.log"
    log.write_text("".join(line for line in log.read_text().splitlines(True) if ",uwb," not in line))
    summary = pipeline.run(load_system(cfg), log).summary
    assert summary["sensors"]["alt"]["malformed"] == 40
    # (the filter's own wording when a model failed on each: which sensor, which model, what, how often)
    why = summary["not_started"]
    assert "every measurement that reached the filter was lost" in why and "no input reached" not in why
    assert "alt: measurement model 'test_height'" in why and "R = [[nan]]" in why and "40 times" in why
