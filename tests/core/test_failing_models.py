"""A plugin's model that raises (or returns the wrong shape) inside the filter's steps (docs/pipeline.md "Ctrl-C,
and a source that fails": a component that fails on a message only loses that message). A measurement model's
h or jacobian: the update is lost, counted malformed for its sensor, one event naming the sensor, the model
and the exception (and the count at the end), the belief kept, the run goes on. A process model that fails on
every prediction: the run stops with exit 2 and a message naming it, the summary written. ``fusion validate``
finds an h of the wrong shape. (None of these is an internal error, exit 1, without a summary.)"""
import json
import textwrap
from pathlib import Path

import numpy as np
import pytest
from pydantic import Field

import fusion.registry
from fusion import pipeline
from fusion.api import MeasurementModel, Params, ProcessModel, StateLayout
from fusion.cli import main
from fusion.config import load_system
from fusion.registry import make_plugin_manager

ROOT = Path(__file__).resolve().parents[2]
BEACONS = {"B1": [0.0, 0.0], "B2": [30.0, 0.0], "B3": [30.0, 20.0], "B4": [0.0, 20.0]}


class BearingParams(Params):
    fault: str = Field("none", description="none|raise_h|shape|raise_jac")


class Bearing(MeasurementModel[BearingParams]):
    """Bearing (rad) from a station at (15, -5) to the position ``p``."""

    name = "test_bearing"
    Params = BearingParams
    dim = 1

    def h(self, x):
        if self.params.fault == "raise_h":
            raise RuntimeError("boom in h")
        z = np.arctan2(x[..., 1] + 5.0, x[..., 0] - 15.0)[..., None]
        return np.concatenate([z, z], axis=-1) if self.params.fault == "shape" else z

    def jacobian(self, x):
        if self.params.fault == "raise_jac":
            raise ValueError("boom in jacobian")
        return None

    def residual(self, z, z_hat):
        return (np.asarray(z) - np.asarray(z_hat) + np.pi) % (2 * np.pi) - np.pi


class CvParams(Params):
    fault: str = Field("none", description="none|raise_f|raise_once")


class Cv(ProcessModel[CvParams]):
    """2-D constant velocity (m, m/s), S = 0.05 m^2/s^3; ``raise_f``: f always raises, ``raise_once``: where
    the states' mean px is within 13 mm of 4 m (one step of the 25 mm the walk makes a step)."""

    name = "test_cv"
    Params = CvParams
    layout = StateLayout.parse("p:2 v:2")

    def f(self, x, u, dt):
        fault = self.params.fault
        if fault == "raise_f" or (fault == "raise_once" and abs(np.mean(np.asarray(x)[..., 0]) - 4.0) < 0.013):
            raise RuntimeError("boom in f")
        y = np.array(x, dtype=float, copy=True)
        y[..., 0:2] = x[..., 0:2] + dt * x[..., 2:4]
        return y

    def Q(self, x, u, dt):
        q = 0.05 * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
        Q = np.zeros((4, 4))
        Q[np.ix_([0, 2], [0, 2])] = q
        Q[np.ix_([1, 3], [1, 3])] = q
        return Q


@pytest.fixture
def registry(monkeypatch):
    _, reg = make_plugin_manager()
    reg.add(Bearing)
    reg.add(Cv)
    monkeypatch.setattr(fusion.registry, "_DEFAULT", reg)
    return reg


def config(tmp_path, fault="none", process="{type: pv, dims: 2, spectral_density: 0.05}", filt="ukf"):
    path = tmp_path / "c.yaml"
    path.write_text(textwrap.dedent(f"""\
        name: failing
        recording: {tmp_path / 'r.log'}
        beacons: {BEACONS}
        process: {process}
        initial: {{mean: {{p: [3.0, 3.0], v: [0.0, 0.0]}}, sd: {{p: 1.0, v: 0.5}}}}
        filter: {filt}
        sensors:
          uwb: {{model: range, noise: {{sd: 0.1}}}}
          brg: {{model: {{type: test_bearing, fault: {fault}}}, noise: {{sd: 0.01}}}}
        output: {{on_update: true}}
        """))
    lines = ["# fields uwb beacon range", "# fields brg bearing", "# fields truth px py vx vy"]
    for k in range(200):
        t = 0.05 * k
        p = np.array([3.0 + 0.5 * t, 3.0])
        b = list(BEACONS)[k % 4]
        lines.append(f"{t:.6f},uwb,{b},{np.linalg.norm(p - BEACONS[b]):.6f}")
        lines.append(f"{t:.6f},truth,{p[0]:.6f},{p[1]:.6f},0.5,0.0")
        if k % 5 == 2:
            lines.append(f"{t:.6f},brg,{np.arctan2(p[1] + 5.0, p[0] - 15.0):.6f}")
    (tmp_path / "r.log").write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("fault,filt", [("raise_h", "ukf"), ("raise_h", "ekf"), ("shape", "ukf"), ("shape", "ekf"),
                                        ("raise_jac", "ekf")])
def test_a_measurement_model_that_raises_in_the_update_loses_only_its_messages(registry, tmp_path, fault, filt):
    good = pipeline.run(load_system(config(tmp_path, filt=filt)), tmp_path / "r.log").summary
    events = []
    result = pipeline.run(load_system(config(tmp_path, fault, filt=filt)), tmp_path / "r.log", on_event=events.append)
    s = result.summary
    brg, uwb = s["sensors"]["brg"], s["sensors"]["uwb"]
    assert brg["received"] == brg["malformed"] == 40 and brg["used"] == 0
    assert uwb == good["sensors"]["uwb"] and s["errors"]["position_rmse_m"] < 0.2   # the run went on
    told = [e for e in events if e.sensor == "brg"]
    assert len(told) == 2, [e.detail for e in told]   # the first failure and the count, not 40 events
    assert "'test_bearing'" in told[0].detail and "line " in told[0].detail
    assert ("boom" in told[0].detail) if fault != "shape" else ("h returned shape (2,)" in told[0].detail
                                                                 and "expected (1,)" in told[0].detail)
    assert "40 times" in told[1].detail


def test_fusion_run_with_a_failing_measurement_model_writes_the_summary(registry, tmp_path, capsys):
    out = tmp_path / "s.json"
    assert main(["run", str(config(tmp_path, "raise_h")), "-q", "--summary-json", str(out)]) == 0
    assert json.loads(out.read_text())["sensors"]["brg"]["malformed"] == 40


def test_a_process_model_that_fails_on_every_prediction_stops_the_run_with_exit_2(registry, tmp_path, capsys):
    cfg = config(tmp_path, process="{type: test_cv, fault: raise_f}")
    out = tmp_path / "s.json"
    assert main(["run", str(cfg), "--summary-json", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "process model 'test_cv' failed" in err and "boom in f" in err and "internal error" not in err
    s = json.loads(out.read_text())
    assert "test_cv" in s["component_error"] and s["sensors"]["uwb"]["received"] > 0


def test_a_process_model_that_fails_once_holds_the_belief_over_that_step(registry, tmp_path):
    events = []
    s = pipeline.run(load_system(config(tmp_path, process="{type: test_cv, fault: raise_once}")), tmp_path / "r.log",
                     on_event=events.append).summary
    assert "component_error" not in s and s["errors"]["position_rmse_m"] < 0.2
    assert [e.kind for e in events if "test_cv" in e.detail] == ["warning", "warning"]   # the first, and the count


def test_validate_finds_an_h_of_the_wrong_shape(registry, tmp_path, capsys):
    assert main(["validate", str(config(tmp_path, "raise_jac"))]) == 0
    capsys.readouterr()
    assert main(["validate", str(config(tmp_path, "shape"))]) == 2
    err = capsys.readouterr().err
    assert "sensors.brg.model" in err and "'test_bearing'" in err and "returned shape (2,), expected (1,)" in err


def test_a_filter_bug_in_an_update_is_still_an_internal_error(registry, tmp_path, monkeypatch):
    """Only the model's fault is charged to its sensor: when the model's h and jacobian work at the belief, an
    update that raises is the filter's bug and ends the run (tests/core/test_cli_run.py: exit 1)."""
    from fusion_plugins.filters.ukf import UnscentedKalmanFilter

    def broken(self, *args, **kwargs):
        raise RuntimeError("filter bug")

    monkeypatch.setattr(UnscentedKalmanFilter, "update", broken)
    with pytest.raises(RuntimeError, match="filter bug"):
        pipeline.run(load_system(config(tmp_path)), tmp_path / "r.log")
