"""The boundary between a filter and a third party's models (plugins/filters/checks.py): a plugin's model is
wrapped at wiring by the checking adapter (``checks.checked``), which gives it read-only views of the filter's
state and checks every value it returns. A bad one (wrong shape, NaN at a finite state, a Q that is
not positive semi-definite) raises ModelFault, which the run charges to the model like an exception of its
own: a measurement's message lost (counted malformed, the model named), a process model's prediction held,
the run stopped with exit 2 after several in a row; ``fusion validate`` probes the process model too."""
from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest
from pydantic import Field

import fusion.registry
from fusion import pipeline, testing
from fusion.api import MeasurementModel, Params, ProcessModel, StateLayout
from fusion.cli import main
from fusion.config import load_system
from fusion.errors import ModelFault
from fusion.registry import make_plugin_manager
from fusion_plugins.filters.checks import checked

FILTERS = ["kf", "ekf", "iekf", "ukf", "srukf"]


class FaultParams(Params):
    fault: str = Field("none", description="which bug")


class Cv1(ProcessModel[FaultParams]):
    """1-D constant velocity p:1 v:1 (m, m/s), white acceleration 0.1 m^2/s^3, with a switchable bug."""

    name = "test_cv1"
    Params = FaultParams
    layout = StateLayout.parse("p:1 v:1")
    linear = True

    def _F(self, dt):
        return np.array([[1.0, dt], [0.0, 1.0]])

    def f(self, x, u, dt):
        fault = self.params.fault
        y = np.asarray(x, dtype=float) @ self._F(dt).T
        if fault == "write":
            x[...] = 0.0          # a correct result, then an in-place op on the argument
        elif fault == "list":
            return y.tolist()
        elif fault == "shape":
            return y[..., :1]
        elif fault == "nan":
            return y * np.nan
        return y

    def jacobian(self, x, u, dt):
        if self.params.fault == "jac_shape":
            return np.eye(3)
        if self.params.fault == "jac_write":
            x[0] += 1.0
        return self._F(dt)

    def Q(self, x, u, dt):
        Q = 0.1 * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
        fault = self.params.fault
        if fault == "q_neg":
            return -Q
        if fault == "q_1d":
            return np.diag(Q)
        if fault == "q_asym":
            return Q + np.array([[0.0, 1e-3], [0.0, 0.0]])
        if fault == "q_indefinite":
            return Q + np.array([[0.0, 1.0], [1.0, 0.0]])
        return Q


class Pos1(MeasurementModel[FaultParams]):
    """The position p (m) of a p:1 v:1 state, with a switchable bug."""

    name = "test_pos1"
    Params = FaultParams
    dim = 1
    linear = True

    def h(self, x):
        fault = self.params.fault
        z = np.asarray(x, dtype=float)[..., :1].copy()
        if fault == "write":
            x[..., 0] += 1000.0
        elif fault == "nan":
            return z * np.nan
        elif fault == "shape":
            return np.concatenate([z, z], axis=-1)
        return z

    def jacobian(self, x):
        if self.params.fault == "jac_write":
            x[0] += 1000.0
        if self.params.fault == "jac_nan":
            return np.array([[np.nan, 0.0]])
        return np.array([[1.0, 0.0]])


def _belief(flt, x=(1.0, 2.0)):
    return flt.initial_belief(0.0, np.array(x), np.diag([4.0, 1.0]))


@pytest.mark.parametrize("name", FILTERS)
@pytest.mark.parametrize("fault", ["write", "jac_write"])
def test_a_process_model_that_writes_into_its_argument_raises_and_the_belief_is_untouched(name, fault):
    flt = testing.build("filter", name)
    b = _belief(flt)
    before = b.x.copy()
    process = checked(Cv1(FaultParams(fault=fault)))
    with pytest.raises(ValueError, match="read-only"):
        flt.predict(b, process, None, 0.1)
    assert np.array_equal(b.x, before)


@pytest.mark.parametrize("name", ["kf", "ekf", "iekf"])
@pytest.mark.parametrize("fault", ["write", "jac_write"])
def test_a_measurement_model_that_writes_into_its_argument_raises_and_the_belief_is_untouched(name, fault):
    flt = testing.build("filter", name)
    b = _belief(flt)
    before = b.x.copy()
    with pytest.raises(ValueError, match="read-only"):
        flt.update(b, checked(Pos1(FaultParams(fault=fault))), np.array([1.1]), np.array([[0.25]]))
    assert np.array_equal(b.x, before)


@pytest.mark.parametrize("name", FILTERS)
def test_f_returning_a_list_is_read_as_an_array(name):
    flt = testing.build("filter", name)
    good = flt.predict(_belief(flt), Cv1(), None, 0.1)
    listed = flt.predict(_belief(flt), checked(Cv1(FaultParams(fault="list"))), None, 0.1)
    assert type(listed.x) is np.ndarray and np.array_equal(listed.x, good.x)


@pytest.mark.parametrize("name", FILTERS)
@pytest.mark.parametrize("fault,match", [
    ("shape", r"f returned shape \(1,\)"),
    ("nan", "f returned NaN or inf"),
    ("q_neg", "Q has a negative variance"),
    ("q_1d", r"Q returned shape \(2,\) at the belief's mean, expected \(2, 2\)"),
    ("q_asym", "Q is not symmetric"),
    ("q_indefinite", "Q is not positive semi-definite"),
    ("jac_shape", r"jacobian returned shape \(3, 3\)"),
])
def test_a_bad_process_model_value_is_a_model_fault(name, fault, match):
    flt = testing.build("filter", name, {"linear_prediction": "always"} if name in ("ukf", "srukf")
                        and fault == "jac_shape" else None)
    with pytest.raises(ModelFault, match=match):
        flt.predict(_belief(flt), checked(Cv1(FaultParams(fault=fault))), None, 0.1)


@pytest.mark.parametrize("name", FILTERS)
def test_nan_from_a_model_at_a_nan_belief_is_not_the_models_fault(name):
    flt = testing.build("filter", name)
    b = _belief(flt, (np.nan, 0.0))
    flt.predict(b, checked(Cv1(FaultParams(fault="nan"))), None, 0.1)   # no ModelFault: the state was NaN already


@pytest.mark.parametrize("name", FILTERS)
@pytest.mark.parametrize("fault,match", [("nan", "h returned NaN or inf"),
                                         ("shape", r"h returned shape \(2,\) .*expected \(1,\)")])
def test_a_bad_measurement_model_value_is_a_model_fault_alike_in_every_filter(name, fault, match):
    flt = testing.build("filter", name)
    with pytest.raises(ModelFault, match=match):
        flt.update(_belief(flt), checked(Pos1(FaultParams(fault=fault))), np.array([1.1]), np.array([[0.25]]))


@pytest.mark.parametrize("name", ["kf", "ekf", "iekf"])
def test_a_nan_measurement_jacobian_is_a_model_fault(name):
    flt = testing.build("filter", name)
    with pytest.raises(ModelFault, match="jacobian returned NaN or inf"):
        flt.update(_belief(flt), checked(Pos1(FaultParams(fault="jac_nan"))), np.array([1.1]), np.array([[0.25]]))


# ---------------------------------------------------------------------------------------------- a run
@pytest.fixture
def registry(monkeypatch):
    _, reg = make_plugin_manager()
    reg.add(Cv1)
    reg.add(Pos1)
    monkeypatch.setattr(fusion.registry, "_DEFAULT", reg)
    return reg


def _config(tmp_path, process="none", meas="none", filt="ekf"):
    path = tmp_path / "c.yaml"
    path.write_text(textwrap.dedent(f"""\
        name: boundary
        recording: {tmp_path / 'r.log'}
        process: {{type: test_cv1, fault: {process}}}
        initial: {{mean: {{p: [0.0], v: [0.5]}}, sd: {{p: 1.0, v: 0.5}}}}
        filter: {filt}
        sensors:
          pos: {{model: {{type: test_pos1, fault: {meas}}}, noise: {{sd: 0.1}}}}
        """))
    rng = np.random.default_rng(1)
    lines = ["# fields pos p", "# fields truth px vx"]
    for k in range(100):
        t = 0.1 * k
        lines.append(f"{t:.6f},pos,{0.5 * t + rng.normal(0, 0.1):.6f}")
        lines.append(f"{t:.6f},truth,{0.5 * t:.6f},0.5")
    (tmp_path / "r.log").write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("filt", FILTERS)
@pytest.mark.parametrize("meas,what", [("write", "read-only"), ("nan", "h returned NaN or inf"),
                                       ("shape", "h returned shape (2,)")])
def test_a_run_loses_the_messages_of_a_bad_measurement_model_and_names_it(registry, tmp_path, filt, meas, what):
    if meas == "write" and filt in ("ukf", "srukf"):
        meas = "none"   # the sigma points are copies: a write is harmless there, the run as the clean one
    out = tmp_path / "s.json"
    code = main(["run", str(_config(tmp_path, meas=meas, filt=filt)), "-q", "--summary-json", str(out)])
    s = json.loads(out.read_text())
    if meas == "none":
        assert code == 0 and s["sensors"]["pos"]["used"] == 100
        return
    assert code == 2 and s["sensors"]["pos"]["malformed"] == 100 and s["sensors"]["pos"]["rejected"] == 0
    assert "every measurement that reached the filter was lost" in s["not_started"]
    assert "'test_pos1'" in s["not_started"] and what in s["not_started"]


@pytest.mark.parametrize("filt", FILTERS)
@pytest.mark.parametrize("process,what", [("write", "read-only"), ("nan", "f returned NaN or inf"),
                                          ("shape", "f returned shape (1,)"), ("q_neg", "negative variance"),
                                          ("q_1d", "Q returned shape (2,)")])
def test_a_run_with_a_bad_process_model_stops_with_exit_2_naming_it(registry, tmp_path, capsys, filt, process,
                                                                    what):
    out = tmp_path / "s.json"
    code = main(["run", str(_config(tmp_path, process=process, filt=filt)), "--summary-json", str(out),
                 "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "internal error" not in err
    assert "process model 'test_cv1' failed in a prediction" in err and what in err
    assert "test_cv1" in json.loads(out.read_text())["component_error"]


def test_the_clean_run_is_good(registry, tmp_path):
    s = pipeline.run(load_system(_config(tmp_path)), tmp_path / "r.log").summary
    assert s["sensors"]["pos"]["used"] == 100 and s["errors"]["position_rmse_m"] < 0.1


@pytest.mark.parametrize("process,meas,what", [
    ("shape", "none", r"process: process model 'test_cv1' (2 states): f returned shape (1,)"),
    ("jac_shape", "none", "jacobian returned shape (3, 3)"),
    ("q_neg", "none", "Q has a negative variance"),
    ("q_1d", "none", "Q returned shape (2,)"),
    ("q_asym", "none", "Q is not symmetric"),
    ("nan", "none", "f returned NaN or inf"),
    ("write", "none", "process model 'test_cv1' writes into the state it is given"),
    ("none", "nan", "sensors.pos.model: measurement model 'test_pos1' (dim 1): h returned NaN or inf"),
    ("none", "jac_nan", "jacobian returned NaN or inf"),
    ("none", "write", "measurement model 'test_pos1' writes into the state it is given"),
])
def test_validate_probes_the_process_model_and_the_measurement_values(registry, tmp_path, capsys, process, meas,
                                                                      what):
    cfg = _config(tmp_path, process=process, meas=meas)
    assert main(["validate", str(cfg)]) == 2
    assert what in capsys.readouterr().err


def test_validate_passes_the_clean_config(registry, tmp_path, capsys):
    assert main(["validate", str(_config(tmp_path))]) == 0
    assert main(["validate", str(_config(tmp_path, meas="jac_nan", filt="ukf"))]) == 0   # the ukf never calls it


# ------------------------------------------------------------------------------ fusion's own models
class _Never(dict):
    """checks._TRUSTED that trusts nothing: every model gets the view and the checks."""

    def get(self, key, default=None):
        return False


@pytest.mark.parametrize("config", ["uwb_pv_ukf", "ultrasonic_3d_iekf", "abps_ins"])
def test_the_shipped_models_pass_every_check_to_the_same_numbers(config, monkeypatch):
    """fusion's own models are not wrapped (checks.trusted, for speed): wrapped, a shipped replay (ukf, iekf,
    srukf with the INS's input runs) raises nothing and gives the same estimates to the bit."""
    from fusion.api import Estimate
    from fusion_plugins.filters import checks

    root = Path(__file__).resolve().parents[2]

    def replay():
        system = load_system(root / "configs" / f"{config}.yaml")
        seen = []

        class Keep:
            def on_estimate(self, e: Estimate):
                seen.append(np.concatenate([[e.t], e.belief.x, e.belief.sd]))

            def close(self):
                pass

        result = pipeline.run(system, system.recording, [Keep()], hooks=False)
        return np.array(seen), result.summary

    trusted, s1 = replay()
    assert checks.trusted(load_system(root / "configs" / f"{config}.yaml").process)
    monkeypatch.setattr(checks, "_TRUSTED", _Never())
    checked, s2 = replay()
    assert trusted.shape == checked.shape and np.array_equal(trusted, checked, equal_nan=True)
    assert s1["sensors"] == s2["sensors"] and "component_error" not in s2


def test_the_adapter_keeps_the_models_class_capabilities_and_state():
    """checked() returns a copy of the model whose class is a subclass of its own (the same name, module and
    capabilities), leaves the model itself as it was, wraps once, and leaves fusion's own models alone."""
    from fusion.api import capabilities_of

    raw = Cv1(FaultParams(fault="write"))
    c = checked(raw)
    assert isinstance(c, Cv1) and type(c) is not Cv1 and type(c).__name__ == "Cv1"
    assert type(c).__module__ == Cv1.__module__ and capabilities_of(c) == capabilities_of(raw)
    assert checked(c) is c and type(raw) is Cv1
    x = np.array([1.0, 2.0])
    raw.f(x, None, 0.1)                                      # the model itself still writes, unwrapped
    assert np.array_equal(x, 0.0 * x)
    own = testing.ConstantVelocity(testing.ConstantVelocity.Params())
    assert checked(own) is own


def test_a_checked_model_pickles_and_copies_as_a_checked_model():
    """The checking class is made at run time: a pickled or deep-copied checked model is checked(its model)."""
    import copy
    import pickle

    c = checked(Cv1(FaultParams(fault="shape")))
    for d in (pickle.loads(pickle.dumps(c)), copy.deepcopy(c)):
        assert type(d) is type(c) and d.params.fault == "shape"
        with pytest.raises(ModelFault, match=r"f returned shape \(1,\)"):
            d.f(np.array([1.0, 2.0]), None, 0.1)


def test_a_model_bound_by_observe_is_checked_too():
    """A plugin's observe() that returns a new model (bound to the message) gets it checked as well."""
    from fusion.api import Message, Observation

    class Bound(Pos1):
        name = "test_bound"

        def observe(self, message):
            return Observation(message.t, np.array([float(message.values[0])]), Pos1(FaultParams(fault="nan")))

    c = checked(Bound(FaultParams()))
    o = c.observe(Message(1.0, "pos", (1.5,), 1))
    assert isinstance(o.model, Pos1) and type(o.model) is not Pos1
    with pytest.raises(ModelFault, match="h returned NaN or inf"):
        o.model.h(np.array([1.0, 2.0]))
