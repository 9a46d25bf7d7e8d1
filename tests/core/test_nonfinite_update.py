"""An update whose prediction is not finite is refused, gate or no gate, for every filter: the belief is
kept, the message counted malformed (the model's fault, not a rejection) with an event naming the
model, and the run goes on (DESIGN: never a
NaN propagated silently): an ungated sensor whose h is NaN at the initial state would otherwise make the
belief NaN at t = 0 and every later measurement rejected."""
from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
import pytest

from fusion import hookimpl, pipeline
from fusion.api import MeasurementModel, Observation, Params
from fusion.config import SystemSpec, wire
from fusion.registry import make_plugin_manager
from fusion.yamlsource import load_yaml


class NanBelowSpeed(MeasurementModel):
    """Speed |v| (m/s) of a p:2 v:2 state; NaN below ``below`` m/s (a third-party model's blind spot)."""

    name: ClassVar[str] = "speed_nan_test"
    dim = 1

    class Params(Params):
        below: float = 0.9

    def h(self, x):
        v = np.asarray(x)[..., 2:4]
        s = np.sqrt((v * v).sum(axis=-1, keepdims=True))
        return np.where(s < self.params.below, np.nan, s)

    def observe(self, message):
        return Observation(message.t, np.array([float(message.values[0])]), self)


class _Plugin:
    @hookimpl
    def fusion_register_components(self, registry):
        registry.add(NanBelowSpeed)


def _system(filter_type: str):
    from pathlib import Path

    cfg = Path(__file__).resolve().parents[2] / "configs" / "uwb_pv_ukf.yaml"
    data = load_yaml(cfg).data
    data["filter"] = {"type": filter_type}
    data["sensors"]["odo"] = {"role": "measurement", "model": {"type": "speed_nan_test"}, "noise": {"sd": 0.1}}
    data["recording"] = str(cfg.parent / data["recording"])
    _, reg = make_plugin_manager(extra_plugins=[_Plugin()])
    return wire(SystemSpec.model_validate(data), registry=reg), cfg.parent / "../recordings/uwb_route1.log"


@pytest.mark.parametrize("filter_type", ["ekf", "ukf", "srukf", "iekf"])
def test_a_nan_prediction_is_refused_and_the_run_goes_on(filter_type):
    system, log = _system(filter_type)
    lines = log.read_text().splitlines()
    # an odometer reading of 1.2 m/s every 50th line, the first at t = 0 where the state's speed is 0
    t_of = [float(ln.split(",")[0]) for ln in lines if ln and ln[0] != "#"]
    odo = [f"{t:.6f},odo,1.2" for t in t_of[::50]]
    body = sorted((ln for ln in lines if ln and ln[0] != "#"), key=lambda ln: float(ln.split(",")[0]))
    merged = [ln for ln in lines if ln.startswith("#")] + sorted(body + odo, key=lambda ln: float(ln.split(",")[0]))
    events = []
    result = pipeline.run(system, merged, on_event=events.append)
    s = result.summary
    assert result.stats.last_finite
    assert s["health"]["nonfinite_estimates"] == 0
    # a model that is NaN at a finite state is at fault: the message is lost, counted malformed (not
    # rejected), the model named once (plugins/filters/checks.py)
    refused = [e for e in events if e.kind == "malformed" and e.sensor == "odo" and "NaN" in e.detail]
    assert len(refused) == 1 and "speed_nan_test" in refused[0].detail and "returned NaN" in refused[0].detail
    assert s["sensors"]["odo"]["malformed"] > 0
    # the ranges go on being used (not every one rejected after the NaN) and the track is good
    assert s["sensors"]["uwb"]["used"] > 0.95 * s["sensors"]["uwb"]["received"]
    assert s["errors"]["position_rmse_m"] < 0.5
    # a refused update never enters the NIS statistics (a NaN would spoil them)
    c, odo = s["consistency"], s["sensors"]["odo"]
    assert math.isfinite(c["nis_mean"]["odo"]) and math.isfinite(c["nees_mean"])
    assert c["nis_samples"]["odo"] == odo["used"] + odo["rejected"]


def test_the_contract_kit_catches_a_model_nan_at_rest():
    from fusion.testing import check_measurement

    layout = _system("ukf")[0].layout                              # p:2 v:2
    with pytest.raises(AssertionError, match="h is not finite at rest"):
        check_measurement(NanBelowSpeed, {"below": 0.9}, layout)
    check_measurement(NanBelowSpeed, {"below": -1.0}, layout)      # never NaN: passes
