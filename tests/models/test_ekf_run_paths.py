"""The fast paths of the paper-002 system (configs/imu_gps_mag_ekf.yaml) against independent references.

* The EKF's batched runs of IMU samples (``ekf.predict_inputs`` through ``InsStates.linearise_inputs``)
  against the scheduler's sample-by-sample prediction (``ekf.predict`` per sample, symmetrised at every
  step), replayed over the shipped recording for the 10-, 16- and 22-state sets, with the recording as is
  and with IMU gaps longer than ``hold_after`` (the run then falls back to per-sample predictions).
* The one-state shortcuts that must give the very numbers of the general code, bit for bit: the run's
  attitude-independent noise, the magnetometer's ``h`` and ``jacobian`` for one state (numpy; its compiled
  kernel to the last bit or two), the truth window's quaternion normalisation and median, the NMEA
  decoder's NED conversion.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fusion import kernels
import yaml
from scipy.spatial.transform import Rotation

from fusion import quaternion as quat
from fusion.api import BuildContext, Estimate, StateLayout
from fusion.config import build_component, load_system
from fusion.logformat import iter_messages
from fusion.pipeline import Run
from fusion.registry import default_registry
from fusion.truth_stream import _median, _Rows
from fusion_plugins.filters.jacobian import numerical_jacobian
from fusion_plugins.measurement import magnetometer
from fusion_plugins.measurement.magnetometer import Magnetometer, MagnetometerParams

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "imu_gps_mag_ekf.yaml"
RECORDING = ROOT / "recordings" / "car_gps_mag.log"
L22 = StateLayout.parse("p:3 v:3 q:4:quaternion ba:3 bw:3 sa:3 sw:3")


# ---------------------------------------------------------------------------- batched vs per-sample runs
def _variant(tmp_path: Path, states: int, gaps: bool) -> tuple[Path, list[str]]:
    """The shipped config with ``states`` on the first 75 s of the shipped recording (the static start
    and ~35 s of driving, GPS fixes and magnetometer updates); with ``gaps``, two IMU gaps (0.1 and 0.3 s)
    longer than hold_after."""
    spec = yaml.safe_load(CONFIG.read_text())
    spec["process"]["states"] = states
    if states != 22:
        for k in ("accel_scale_rw", "gyro_scale_rw"):
            spec["process"].pop(k)
        keep = {10: ("p", "v", "q"), 16: ("p", "v", "q", "ba", "bw")}[states]
        for k in ("mean", "sd"):
            spec["initial"][k] = {b: v for b, v in spec["initial"][k].items() if b in keep}
    spec["recording"] = str(RECORDING)
    path = tmp_path / f"imu_gps_mag_{states}.yaml"
    path.write_text(yaml.safe_dump(spec))
    lines = []
    for line in RECORDING.read_text().splitlines():
        if not line.startswith("#"):
            t, sensor = line.split(",", 2)[:2]
            if float(t) > 75.0:
                break
            if gaps and sensor == "imu" and (50.0 < float(t) < 50.1 or 61.0 < float(t) < 61.3):
                continue
        lines.append(line)
    return path, lines


def _estimates(config: Path, lines: list[str], batched: bool) -> tuple[list[Estimate], dict]:
    class Keep:
        def __init__(self):
            self.out = []

        def on_estimate(self, e):
            self.out.append(e)

        def close(self):
            pass

    sink = Keep()
    run = Run(load_system(config), [sink], hooks=False)
    run.loop.integrator.batch = batched and run.loop.integrator.batch
    run.consume(iter_messages(lines, run.parsed))
    result = run.finish()
    return sink.out, result.summary


@pytest.mark.parametrize("states", [10, 16, 22])
@pytest.mark.parametrize("gaps", [False, True])
def test_batched_runs_equal_sample_by_sample_predictions(tmp_path, states, gaps):
    config, lines = _variant(tmp_path, states, gaps)
    got, summary = _estimates(config, lines, batched=True)
    ref, ref_summary = _estimates(config, lines, batched=False)
    if states != 16:      # the 16-state ins has no run linearisation: k predictions either way
        assert summary["filter_counters"]["batched_predicts"] > 100
    assert "batched_predicts" not in ref_summary["filter_counters"]
    assert summary["steps"] == ref_summary["steps"] and summary["sensors"] == ref_summary["sensors"]
    assert len(got) == len(ref) > 200
    for a, b in zip(got, ref):
        assert a.t == b.t and a.reason == b.reason and a.sensor == b.sensor
        # rounding only: the per-sample path symmetrises P at every sample, the run at its end
        np.testing.assert_allclose(a.belief.x, b.belief.x, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(a.belief.P, b.belief.P, rtol=1e-7, atol=1e-15)


# ---------------------------------------------------------------------------- bit-for-bit shortcuts
def _ins(states: int):
    extra = {"accel_scale_rw": 1e-4, "gyro_scale_rw": 2e-4} if states == 22 else {}
    return build_component(default_registry(), "process",
                           {"type": "ins", "states": states, "integration": "euler", "eta": 0.0,
                            "gravity": 9.80665, "accel_noise_density": 3.4e-3, "gyro_noise_density": 8.7e-4,
                            "accel_bias_rw": 5e-3, "gyro_bias_rw": 5e-5, "hold_after": 0.03, **extra},
                           BuildContext())


@pytest.mark.parametrize("states", [10, 22])
def test_run_noise_base_is_the_per_sample_base(states):
    m = _ins(states)
    dts = np.array([0.006667000000007306, 0.01999999999999602, 0.020000000000010232, 0.013333000000002926,
                    0.02, 0.0299])
    Q = m._q_base_run(dts)
    for Qj, dt in zip(Q, dts.tolist()):
        np.testing.assert_array_equal(Qj, m._q_base(dt))


@pytest.mark.parametrize("compiled", [False, True])
def test_magnetometer_one_state_is_the_general_model(compiled, monkeypatch):
    """The numpy one-state code: bit for bit the general code; the compiled kernel (_magnetometer_kernel.c):
    the same formulas, to the last bit or two."""
    if compiled and magnetometer.KERNEL is None and kernels.missing_allowed():
        pytest.skip("the magnetometer kernel is not built (python setup.py build_ext --inplace)")
    if not compiled:
        monkeypatch.setattr(magnetometer, "KERNEL", None)

    def same(a, b):
        if compiled:
            np.testing.assert_allclose(a, b, rtol=0, atol=4e-16 * np.abs(b).max())
        else:
            np.testing.assert_array_equal(a, b)

    rng = np.random.default_rng(5)
    mag = Magnetometer(MagnetometerParams(declination_deg=-20.5, inclination_deg=-36.0, intensity=23.5),
                       BuildContext(layout=L22))
    X = rng.normal(size=(200, 22))
    X[:, 6:10] = Rotation.random(200, random_state=rng).as_quat(scalar_first=True) * rng.uniform(0.9, 1.1, (200, 1))
    Z = mag.h(X)
    flip = np.array([1.0, -1.0, -1.0, -1.0])
    for x, z in zip(X, Z):
        same(mag.h(x), quat.rotate(x[6:10] * flip, mag.m_n))              # the general code on (4,)
        np.testing.assert_allclose(mag.h(x), z, rtol=1e-13, atol=1e-13)   # a batch rounds in another order
        H = np.zeros((3, 22))
        H[:, 6:10] = quat.rotate_jacobian(x[6:10] * flip, mag.m_n) * flip
        same(mag.jacobian(x), H)
    np.testing.assert_allclose(mag.jacobian(X[0]), numerical_jacobian(mag.h, X[0]), atol=1e-7)


def test_truth_rows_normalised_as_numpy_does():
    rng = np.random.default_rng(6)
    rows = [tuple(v) for v in (rng.normal(size=(500, 10)) * rng.choice([1e-3, 1.0, 1e3], (500, 1))).tolist()]
    rows.append((1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.0, 4.0, 5.0, 6.0))       # a zero quaternion stays as is
    quats = {"q": [3, 4, 5, 6]}
    got = _Rows(rows, quats)
    for i, v in enumerate(rows):
        ref = np.array(v)
        q = ref[None, quats["q"]]
        nrm = np.linalg.norm(q, axis=1, keepdims=True)
        ref[quats["q"]] = np.divide(q, nrm, out=q.copy(), where=nrm > 0)[0]
        np.testing.assert_array_equal(got[i], ref)


def test_median_is_numpys():
    rng = np.random.default_rng(7)
    for n in (1, 2, 3, 64, 1023, 1024):
        v = (0.02 + 1e-12 * rng.normal(size=n)).tolist()
        assert _median(v) == float(np.median(v))


def test_nmea_ned_is_pymap3ds():
    import pymap3d

    dec = build_component(default_registry(), "decoder", {"type": "nmea", "origin": {
        "lat_deg": -23.21, "lon_deg": -45.876, "alt_m": 600.2}}, BuildContext())
    rng = np.random.default_rng(8)
    for lat, lon, h in zip(-23.21 + 0.01 * rng.normal(size=50), -45.876 + 0.01 * rng.normal(size=50),
                           600 + 10 * rng.normal(size=50)):
        assert dec._ned(pymap3d, lat, lon, h) == pymap3d.geodetic2ned(lat, lon, h, *dec.origin)


def test_gauss_legendre_literals_are_numpys():
    from fusion_plugins.process import ins_batch

    nodes, weights = np.polynomial.legendre.leggauss(4)
    # leggauss's last bits change between numpy releases (its weights by 2 ulp from 1.26 to 2.x): a few ulp
    eps = np.finfo(float).eps
    np.testing.assert_allclose(ins_batch._GL_NODES, 0.5 * (nodes + 1.0), rtol=8 * eps, atol=0)
    np.testing.assert_allclose(ins_batch._GL_WEIGHTS, 0.5 * weights, rtol=8 * eps, atol=0)
