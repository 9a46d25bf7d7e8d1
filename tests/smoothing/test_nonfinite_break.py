"""A belief that turns non-finite (the filter diverged: a third-party f returning NaN, an update with a NaN
innovation) breaks the smoothing chain there, as a recovery reset does (G = 0): the smoothed estimates
before it are those of the run cut at the divergence, finite, for the full and the fixed-lag smoother;
the estimates after it stay the filter's NaN. The summary's errors are over the finite estimates, with
their count (not NaN for every smoothed estimate of a run whose filter diverged part-way, nor a finite
position max next to a None RMSE)."""
from __future__ import annotations

import math
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from fusion import hookimpl, pipeline, testing
from fusion.config import SystemSpec, wire
from fusion.registry import make_plugin_manager
from fusion.smoothing import run_smoothed
from fusion.yamlsource import load_yaml
from fusion_plugins.process.pv import ConstantVelocity
from smoothing_models import Swing, cov, smooth_sequence

DT = 0.1
ROOT = Path(__file__).resolve().parents[2]


class NanSwing(Swing):
    """The swing whose f returns NaN once ``fault`` is set (a third-party model's failure)."""

    fault = False

    def f(self, x, u, dt):
        y = super().f(x, u, dt)
        return y * np.nan if self.fault else y


@pytest.fixture(autouse=True)
def nan_models_trusted(monkeypatch):
    """The filters now refuse an f that returns NaN at a finite state (ModelFault, the model's failure:
    tests/filters/test_model_boundary.py); these models are trusted as fusion's own are (no checks), so that
    the belief does turn non-finite, which is what the smoother's break is tested on."""
    from fusion_plugins.filters import checks

    monkeypatch.setitem(checks._TRUSTED, NanSwing, True)
    monkeypatch.setitem(checks._TRUSTED, NanPv, True)


def _steps(proc, seed=3, N=40):
    rng = np.random.default_rng(seed)
    meas = testing.RangeMeasurement(testing.RangeMeasurement.Params(beacons=[[0.0, 3.0], [2.0, -1.0]], n=2))
    R = np.eye(2) * 0.05 ** 2
    x = np.array([1.0, 0.0])
    steps = []
    for _ in range(N):
        x = Swing().f(x, None, DT) + rng.multivariate_normal(np.zeros(2), proc.Q(x, None, DT))
        steps += [("predict", (None, DT)), ("update", (meas, meas.h(x) + rng.normal(0.0, 0.05, 2), R))]
    return meas, R, steps


def _finite(b) -> bool:
    return bool(np.isfinite(b.x).all() and np.isfinite(cov(b)).all())


@pytest.mark.parametrize("name", ["ekf", "ukf", "srukf"])
@pytest.mark.parametrize("where", ["predict", "update"])
def test_smoothed_before_the_divergence_is_the_run_cut_there(name, where):
    x0, P0 = np.array([0.8, 0.1]), np.diag([0.2, 0.2])
    proc = NanSwing()
    meas, R, steps = _steps(proc)
    cut = 40 if where == "predict" else 41     # the step that diverges: the 21st predict, or its update
    if where == "predict":
        diverging = steps[:cut] + [("call", lambda: setattr(proc, "fault", True))] + steps[cut:]
    else:                                       # an update whose innovation is NaN (no gate, no scheduler)
        diverging = steps[:cut] + [("update", (meas, np.array([np.nan, 1.0]), R))] + steps[cut + 1:]
    filtered, smoothed, _ = smooth_sequence(testing.build("filter", name), proc, diverging, x0, P0)
    proc.fault = False
    _, ref, _ = smooth_sequence(testing.build("filter", name), proc, steps[:cut], x0, P0)
    ok = [_finite(b) for b in filtered]
    assert ok[:cut + 1] == [True] * (cut + 1) and not any(ok[cut + 1:])   # the filter diverged at cut
    assert len(ref) == cut + 1
    for a, b in zip(smoothed[:cut + 1], ref):                  # the run cut there, exactly
        np.testing.assert_array_equal(a.x, b.x)
        np.testing.assert_array_equal(cov(a), cov(b))
    np.testing.assert_array_equal(smoothed[cut].x, filtered[cut].x)   # at the break: the filtered one
    assert not any(_finite(b) for b in smoothed[cut + 1:])      # after: the filter's NaN, nothing made up


class NanPv(ConstantVelocity):
    """pv whose f returns NaN once the mean px passes ``nan_above`` m (a constant-velocity model that diverges)."""

    name: ClassVar[str] = "pv_nan_test"

    class Params(ConstantVelocity.Params):
        nan_above: float = 1e9

    def f(self, x, u, dt):
        y = super().f(x, u, dt)
        return y * np.nan if dt > 0 and np.mean(np.asarray(x)[..., 0]) > self.params.nan_above else y


class _Plugin:
    @hookimpl
    def fusion_register_components(self, registry):
        registry.add(NanPv)


def _system(filter_type: str, nan_above: float):
    cfg = ROOT / "configs" / "uwb_pv_ukf.yaml"
    data = load_yaml(cfg).data
    data["process"] = {**data["process"], "type": "pv_nan_test", "nan_above": nan_above}
    data["filter"] = {"type": filter_type, "linear_prediction": "never"} if "ukf" in filter_type else {"type": filter_type}
    data["recording"] = str(cfg.parent / data["recording"])
    _, reg = make_plugin_manager(extra_plugins=[_Plugin()])
    return wire(SystemSpec.model_validate(data), registry=reg)


@pytest.fixture(scope="module")
def lines():
    system = _system("ekf", 1e9)
    with open(system.recording) as fh:
        return [ln for ln in fh if ln.startswith("#") or float(ln.split(",", 1)[0]) <= 40.0]


@pytest.mark.parametrize("filter_type", ["ekf", "ukf", "srukf"])
@pytest.mark.parametrize("lag", [None, 2.0])
def test_a_run_that_diverges_keeps_its_smoothed_estimates_before(lines, filter_type, lag):
    plain = pipeline.Collect()
    pipeline.run(_system(filter_type, 1e9), lines, [plain])
    px = np.array([e.belief.x[0] for e in plain.estimates])
    nan_above = float(np.quantile(px, 0.5))        # diverges about half-way (where px first passes it)
    system = _system(filter_type, nan_above)
    fw, sm = pipeline.Collect(), pipeline.Collect()
    res = run_smoothed(system, lines, [sm], lag=lag, forward_sinks=[fw])
    s = res.summary
    fin = np.array([bool(np.isfinite(e.belief.x).all()) for e in fw.estimates])
    assert 20 < fin.sum() < len(fin) - 20 and not fin[fin.argmin():].any()   # finite, then NaN to the end
    sfin = np.array([bool(np.isfinite(e.belief.x).all() and np.isfinite(e.belief.sd).all()) for e in sm.estimates])
    assert np.array_equal(sfin, fin)               # not all NaN (full smoother), nor 40 fewer (lag 2 s)
    assert s["smoothed"]["breaks"] == s["smoothed"]["nonfinite_breaks"] == 1
    for errors in (s["errors"], s["smoothed"]["errors"]):
        # over the finite estimates, with their count; never a finite max next to a None RMSE
        assert math.isfinite(errors["position_rmse_m"]) and math.isfinite(errors["velocity_rmse_mps"])
        assert errors["position_max_m"] >= errors["position_rmse_m"]
        assert errors["samples"] > 0 and errors["nonfinite_samples"] > 0
        assert errors["samples"] + errors["nonfinite_samples"] <= len(fin)
    assert s["smoothed"]["errors"]["samples"] == s["errors"]["samples"]
    assert s["smoothed"]["errors"]["position_rmse_m"] < s["errors"]["position_rmse_m"]
    assert s["smoothed"]["consistency"]["nees_skipped"] == s["errors"]["nonfinite_samples"]
