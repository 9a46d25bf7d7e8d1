"""The magnetometer's compiled h and Jacobian for one state (plugins/measurement/_magnetometer_kernel.c)
against the numpy code (itself bit for bit quat.rotate / rotate_jacobian: test_ekf_run_paths.py) and
central differences, on state sets with the q block at different places; and the model's fallback to numpy
for what the kernel refuses."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion import kernels
from fusion.api import BuildContext, StateLayout
from fusion_plugins.filters.jacobian import numerical_jacobian
from fusion_plugins.measurement import magnetometer
from fusion_plugins.measurement.magnetometer import Magnetometer, MagnetometerParams

KERNEL = magnetometer.KERNEL
pytestmark = pytest.mark.skipif(KERNEL is None and kernels.missing_allowed(), reason="_magnetometer_kernel not built (python setup.py "
                                "build_ext --inplace) or FUSION_PURE_PYTHON set")
LAYOUTS = ["p:3 v:3 q:4:quaternion", "p:3 v:3 q:4:quaternion ba:3 bw:3",
           "p:3 v:3 q:4:quaternion ba:3 bw:3 sa:3 sw:3", "q:4:quaternion", "b:2 q:4:quaternion c:1"]


def _model(spec: str, **kw) -> Magnetometer:
    params = MagnetometerParams(declination_deg=-20.5, inclination_deg=-36.0, intensity=23.5, **kw)
    return Magnetometer(params, BuildContext(layout=StateLayout.parse(spec)))


@pytest.mark.parametrize("spec", LAYOUTS)
@pytest.mark.parametrize("direction_only", [False, True])
def test_kernel_is_the_numpy_code(spec, direction_only, monkeypatch):
    mag = _model(spec, direction_only=direction_only)
    rng = np.random.default_rng(len(spec))
    X = rng.normal(size=(50, mag.n))
    q = mag._q
    X[:, q] = Rotation.random(50, random_state=rng).as_quat(scalar_first=True) * rng.uniform(0.5, 2.0, (50, 1))
    got = [(mag.h(x), mag.jacobian(x)) for x in X]
    monkeypatch.setattr(magnetometer, "KERNEL", None)
    for x, (h, H) in zip(X, got):
        h_ref, H_ref = mag.h(x), mag.jacobian(x)
        np.testing.assert_allclose(h, h_ref, rtol=1e-14, atol=1e-15 * np.abs(h_ref).max())
        np.testing.assert_allclose(H, H_ref, rtol=1e-13, atol=1e-15 * np.abs(H_ref).max())
        assert H.shape == (3, mag.n)
        assert np.all(np.delete(H, np.arange(mag.n)[q], axis=1) == 0.0)     # no sensitivity to other states


def test_kernel_jacobian_against_central_differences():
    mag = _model(LAYOUTS[2])
    rng = np.random.default_rng(2)
    x = rng.normal(size=22)
    np.testing.assert_allclose(mag.jacobian(x), numerical_jacobian(mag.h, x), atol=1e-7)


def test_model_falls_back_to_numpy_for_what_the_kernel_refuses(monkeypatch):
    """float32, strided or list states: the numpy code's numbers (the kernel takes contiguous float64 only)."""
    mag = _model(LAYOUTS[2])
    rng = np.random.default_rng(3)
    x = rng.normal(size=22)
    strided = np.repeat(x, 2)[::2]
    x32 = x.astype(np.float32)
    got = [(mag.h(v), mag.jacobian(v)) for v in (strided, x32)]
    got_list = mag.jacobian(list(x))
    monkeypatch.setattr(magnetometer, "KERNEL", None)
    for v, (h, H) in zip((strided, x32), got):
        np.testing.assert_array_equal(h, mag.h(v))
        np.testing.assert_array_equal(H, mag.jacobian(v))
    np.testing.assert_array_equal(got_list, mag.jacobian(list(x)))


@pytest.mark.parametrize("call, error, words", [
    (lambda: KERNEL.h(np.zeros(9), 6, np.ones(3), np.empty(3)), ValueError, "x[6:10] is outside x (9 states)"),
    (lambda: KERNEL.h(np.zeros(10), -1, np.ones(3), np.empty(3)), ValueError, "outside x"),
    (lambda: KERNEL.h(np.zeros(10), 6, np.ones(2), np.empty(3)), ValueError, "m_n has length 2"),
    (lambda: KERNEL.h(np.zeros(10), 6, np.ones(3), np.empty(4)), ValueError, "out has length 4"),
    (lambda: KERNEL.h(np.zeros(10, np.float32), 6, np.ones(3), np.empty(3)), TypeError, "x must be a float64"),
    (lambda: KERNEL.jacobian(np.zeros(10), 6, np.ones(3), np.empty((3, 9))), ValueError, "out has length 9"),
    (lambda: KERNEL.jacobian(np.zeros(10), 6, np.ones(3), np.empty(30)), ValueError, "out must have 2"),
    (lambda: KERNEL.jacobian(np.zeros(10), 6.0, np.ones(3), np.empty((3, 10))), TypeError, "integer"),
])
def test_kernel_refuses_bad_input(call, error, words):
    with pytest.raises(error) as e:
        call()
    assert words in str(e.value)
