"""The compiled run of IMU samples (plugins/process/_ins_run_kernel.c) against its numpy reference
(``ins_linearise.linearise_run_numpy``, ``InsStates._q_base_run``'s numpy sums), and its refusal of bad input.

The numpy code is itself checked against the per-sample fast path and central differences
(tests/models/test_ins_linearise.py); here the kernel must give its numbers to rounding on seeded random runs
(10 and 22 states; 1, 2, 9 and 40 samples; ordinary, tiny (|h| <= 1e-4: the series branch) and zero rotations;
unit and non-unit quaternions, renormalised chain or not; varying intervals)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion import kernels
from fusion_plugins.process import ins_linearise
from fusion_plugins.process.ins_linearise import linearise_run, linearise_run_numpy

KERNEL = ins_linearise.KERNEL
pytestmark = pytest.mark.skipif(KERNEL is None and kernels.missing_allowed(), reason="_ins_run_kernel not built (python setup.py build_ext "
                                "--inplace) or FUSION_PURE_PYTHON set")
G = 9.80665
VAR_W = (8.7e-4) ** 2
QNV = 1e-12


def _state(rng, n: int, q_scale: float) -> np.ndarray:
    x = np.zeros(n)
    x[0:6] = rng.normal(0, 30, 6)
    x[6:10] = Rotation.random(random_state=rng).as_quat(scalar_first=True) * q_scale
    if n == 22:
        x[10:13] = rng.normal(0, 0.1, 3)
        x[13:16] = rng.normal(0, 0.01, 3)
        x[16:22] = 1.0 + rng.normal(0, 0.03, 6)
    return x


def _run(rng, n: int, k: int, rotation: str) -> tuple[np.ndarray, np.ndarray]:
    us = np.empty((k, 6))
    us[:, :3] = rng.normal(0, 2, (k, 3)) + [0.0, 0.0, -G]
    dts = rng.uniform(0.005, 0.03, k)
    if rotation == "ordinary":
        us[:, 3:] = rng.normal(0, 0.8, (k, 3))
    elif rotation == "tiny":                  # |h| = |w| dt / 2 <= 1e-4 after the bias and scale correction
        us[:, 3:] = rng.normal(0, 1e-3, (k, 3))
    else:                                     # s = 0 exactly: the corrected rate is zero
        us[:, 3:] = 0.0
    return us, dts


def _close(a: np.ndarray, b: np.ndarray) -> None:
    """Entry by entry to 1e-12 relative, or to 1e-15 of the array's largest entry (cancellations)."""
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15 * max(np.abs(b).max(), 1e-300))


@pytest.mark.parametrize("n", [10, 22])
@pytest.mark.parametrize("k", [1, 2, 9, 40])
@pytest.mark.parametrize("rotation", ["ordinary", "tiny", "zero"])
@pytest.mark.parametrize("q_scale", [1.0, 1.3])
def test_kernel_is_the_numpy_run(n, k, rotation, q_scale):
    rng = np.random.default_rng(1000 * n + 10 * k + len(rotation) + int(10 * q_scale))
    for _ in range(4):
        x = _state(rng, n, q_scale)
        us, dts = _run(rng, n, k, rotation)
        if rotation != "ordinary" and n == 22:    # the gyro reads its bias (+ a tiny rate): w = (u - b) / s
            us[:, 3:] += x[13:16]
        if rotation == "tiny":
            w = us[:, 3:] if n == 10 else (us[:, 3:] - x[13:16]) / x[19:22]
            assert (0.5 * np.linalg.norm(w, axis=1) * dts).max() <= 1e-4
        Q_base = rng.normal(size=(k, n, n))
        for unit in (True, False):
            ref = linearise_run_numpy(x, us, dts, G, unit, Q_base.copy(), VAR_W, QNV)
            got = linearise_run(x, us, dts, G, unit, Q_base.copy(), VAR_W, QNV)
            for a, b in zip(got, ref):
                assert a.shape == b.shape and a.dtype == np.float64
                _close(a, b)
            if rotation == "zero" and not unit:   # dq = [1, 0, 0, 0]: the attitude is kept exactly
                np.testing.assert_array_equal(got[0][6:10], x[6:10])


def test_kernel_leaves_q_base_outside_the_q_block():
    """The caller's Q_base is completed in place: only its q block is written."""
    rng = np.random.default_rng(3)
    x = _state(rng, 22, 1.0)
    us, dts = _run(rng, 22, 5, "ordinary")
    Q_base = rng.normal(size=(5, 22, 22))
    before = Q_base.copy()
    _, _, Q = linearise_run(x, us, dts, G, True, Q_base, VAR_W, QNV)
    assert Q is Q_base
    mask = np.ones((22, 22), bool)
    mask[6:10, 6:10] = False
    np.testing.assert_array_equal(Q[:, mask], before[:, mask])


def test_noise_base_is_the_numpy_sums():
    """InsStates._q_base_run: dt c1 + dt^2 c2 + dt^3 c3 elementwise, in C the very same operations."""
    rng = np.random.default_rng(4)
    for n in (10, 22):
        dts = rng.uniform(0.005, 0.03, 9)
        c1, c2, c3 = (rng.normal(size=n * n) for _ in range(3))
        Q = np.empty((9, n, n))
        KERNEL.noise_base(dts, c1, c2, c3, Q)
        d2 = dts * dts
        ref = np.multiply.outer(dts, c1)
        ref += np.multiply.outer(d2, c2)
        ref += np.multiply.outer(d2 * dts, c3)
        np.testing.assert_array_equal(Q, ref.reshape(9, n, n))


def test_wrapper_accepts_strided_input():
    """linearise_run hands the kernel contiguous float64 copies of strided or Fortran-ordered arrays."""
    rng = np.random.default_rng(5)
    x = _state(rng, 22, 1.0)
    us, dts = _run(rng, 22, 6, "ordinary")
    wide = np.zeros((6, 12))
    wide[:, ::2] = us
    ref = linearise_run_numpy(x, us, dts, G, True, np.zeros((6, 22, 22)), VAR_W, QNV)
    for u in (wide[:, ::2], np.asfortranarray(us)):
        got = linearise_run(x, u, np.repeat(dts, 2)[::2], G, True, np.zeros((6, 22, 22)), VAR_W, QNV)
        for a, b in zip(got, ref):
            _close(a, b)


def _args(n=22, k=3):
    rng = np.random.default_rng(6)
    x = _state(rng, n, 1.0)
    us, dts = _run(rng, n, k, "ordinary")
    return dict(x=x, us=us, dts=dts, x1=np.empty(n), F=np.empty((k, n, n)), Q=np.zeros((k, n, n)))


def _call(a):
    return KERNEL.linearise(a["x"], a["us"], a["dts"], G, True, VAR_W, QNV, a["x1"], a["F"], a["Q"])


@pytest.mark.parametrize("field, bad, error, words", [
    ("x", np.zeros(16), ValueError, "10 or 22 states"),
    ("x", np.zeros(22, np.float32), TypeError, "x must be a float64 array"),
    ("x", [0.0] * 22, TypeError, "x must be a float64 array (buffer protocol), got list"),
    ("us", np.zeros((3, 5)), ValueError, "us has length 5 along axis 1"),
    ("us", np.zeros((0, 6)), ValueError, "at least one sample"),
    ("us", np.zeros((3, 6), np.int64), TypeError, "us must be a float64 array"),
    ("us", np.zeros((6, 3)).T, ValueError, "C-contiguous"),
    ("dts", np.zeros(4), ValueError, "dts has length 4 along axis 0, expected 3"),
    ("dts", np.zeros((3, 1)), ValueError, "dts must have 1 dimension"),
    ("x1", np.empty(10), ValueError, "x1 has length 10"),
    ("F", np.empty((3, 22, 21)), ValueError, "F has length 21 along axis 2"),
    ("F", np.empty((2, 22, 22)), ValueError, "F has length 2 along axis 0"),
    ("Q", np.empty((3, 22, 22), np.float32), TypeError, "Q must be a float64 array"),
    ("Q", None, TypeError, "got NoneType"),
])
def test_kernel_refuses_bad_input(field, bad, error, words):
    a = _args()
    a[field] = bad
    with pytest.raises(error) as e:
        _call(a)
    assert words in str(e.value)


def test_kernel_refuses_read_only_outputs():
    for field in ("x1", "F", "Q"):
        a = _args()
        a[field].flags.writeable = False
        with pytest.raises(ValueError, match=f"{field} is read-only"):
            _call(a)
    a = _args()
    a["x"].flags.writeable = False                 # read-only inputs are fine
    _call(a)


def test_noise_base_refuses_bad_input():
    dts = np.full(2, 0.02)
    c = np.zeros(100)
    with pytest.raises(ValueError, match="Q must be .k, n, n."):
        KERNEL.noise_base(dts, c, c, c, np.empty((2, 10, 9)))
    with pytest.raises(ValueError, match="c2 has length 99"):
        KERNEL.noise_base(dts, c, c[:99], c, np.empty((2, 10, 10)))
    with pytest.raises(ValueError, match="Q has length 3 along axis 0, expected 2"):
        KERNEL.noise_base(dts, c, c, c, np.empty((3, 10, 10)))
    with pytest.raises(TypeError):
        KERNEL.noise_base(dts, c, c, c)


def test_one_call_with_the_noise_coefficients_is_the_two_calls():
    """linearise(..., c1, c2, c3) (InsStates.linearise_inputs' one call) fills Q's base as noise_base does."""
    rng = np.random.default_rng(7)
    for n in (10, 22):
        x = _state(rng, n, 1.0)
        us, dts = _run(rng, n, 9, "ordinary")
        c = [rng.normal(size=n * n) for _ in range(3)]
        one = (np.empty(n), np.empty((9, n, n)), np.full((9, n, n), np.nan))
        KERNEL.linearise(x, us, dts, G, True, VAR_W, QNV, *one, *c)
        two = (np.empty(n), np.empty((9, n, n)), np.empty((9, n, n)))
        KERNEL.noise_base(dts, *c, two[2])
        KERNEL.linearise(x, us, dts, G, True, VAR_W, QNV, *two)
        for a, b in zip(one, two):
            np.testing.assert_array_equal(a, b)
    with pytest.raises(TypeError, match="c1, c2, c3 together"):
        KERNEL.linearise(x, us, dts, G, True, VAR_W, QNV, *two, c[0])
    with pytest.raises(ValueError, match="c2 has length"):
        KERNEL.linearise(x, us, dts, G, True, VAR_W, QNV, *two, c[0], c[1][:5], c[2])
