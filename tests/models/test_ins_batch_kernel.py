"""The compiled kernel of the INS run integration (plugins/process/_ins_batch_kernel.c) against its numpy
references (k calls of Ins.f, the one numpy propagation; ins_batch.interval_noise_numpy): the same numbers to
rounding on seeded random inputs, clear errors on bad arguments, and the same estimates from `fusion run
configs/abps_ins.yaml` with and without it (FUSION_PURE_PYTHON=1)."""
from __future__ import annotations

import csv
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fusion import kernels, testing
from fusion_plugins.process import ins_batch

K = ins_batch._KERNEL
needs_kernel = pytest.mark.skipif(K is None and kernels.missing_allowed(), reason="compiled kernel not built (python setup.py build_ext "
                                  "--inplace) or FUSION_PURE_PYTHON set")
ROOT = Path(__file__).resolve().parents[2]
G_COL = np.array([[0.02], [-0.01], [9.80665]])
BLOCKS = (slice(0, 3), slice(3, 6), slice(6, 10), slice(10, 16))   # p, v, q, biases


def states(rng, N, q_scale=1.0):
    """N random states (N, 16): metres, m/s, a quaternion of norm q_scale, biases of a low-cost IMU."""
    x = np.empty((N, 16))
    x[:, 0:3] = rng.normal(size=(N, 3)) * 10.0
    x[:, 3:6] = rng.normal(size=(N, 3))
    q = rng.normal(size=(N, 4))
    x[:, 6:10] = q / np.linalg.norm(q, axis=1, keepdims=True) * q_scale
    x[:, 10:13] = rng.normal(size=(N, 3)) * 0.05
    x[:, 13:16] = rng.normal(size=(N, 3)) * 0.01
    return x


def samples(rng, k, rate_sd=0.5):
    us = np.column_stack([rng.normal(size=(k, 3)) * 2.0 + [0.0, 0.0, -9.8], rng.normal(size=(k, 3)) * rate_sd])
    return us, 0.01 + 0.004 * rng.random(k)                 # uneven intervals (jitter), s


_INS: dict[bool, object] = {}


def integrate_reference(x, us, dts, g_col, trapezoidal):
    """k calls of Ins.f (eta 0, no Earth rate, no hold), with gravity g_col (3, 1): the kernel's reference."""
    ins = _INS.get(trapezoidal)
    if ins is None:
        ins = _INS[trapezoidal] = testing.build("process", "ins",
                                                {"integration": "trapezoidal" if trapezoidal else "euler"})
    ins._g_col = np.asarray(g_col, dtype=float).reshape(3, 1)   # the kernel takes any g_n; the model's is vertical
    for u, dt in zip(us, dts):
        x = ins.f(x, u, float(dt))
    return x


def assert_blockwise_close(a, b, rel=1e-12):
    """Each element within ``rel`` of the largest magnitude of its block (p, v, q, biases) in that state: a
    relative test that an element near zero by cancellation does not turn into a test of its last bits."""
    a, b = np.atleast_2d(a), np.atleast_2d(b)
    for blk in BLOCKS:
        scale = np.abs(b[..., blk]).max(axis=-1, keepdims=True)
        assert np.all(np.abs(a[..., blk] - b[..., blk]) <= rel * scale), (blk, np.abs(a - b).max())


@needs_kernel
@pytest.mark.parametrize("trapezoidal", [True, False])
@pytest.mark.parametrize("k", [1, 2, 15, 16, 40, 100])
@pytest.mark.parametrize("N", [1, 33])
def test_integrate_matches_sample_by_sample(N, k, trapezoidal):
    rng = np.random.default_rng(1000 * N + k)
    x = states(rng, N)
    us, dts = samples(rng, k)
    got = ins_batch.integrate_inputs(x, us, dts, G_COL, trapezoidal)
    ref = integrate_reference(x, us, dts, G_COL, trapezoidal)
    assert got.shape == ref.shape == (N, 16)
    assert_blockwise_close(got, ref)
    assert np.array_equal(got[:, 10:], x[:, 10:])          # biases and what follows: kept exactly


@needs_kernel
@pytest.mark.parametrize("trapezoidal", [True, False])
@pytest.mark.parametrize("rate", ["zero", "tiny"])
def test_integrate_zero_and_tiny_rotations(rate, trapezoidal):
    """A gyro reading equal to the bias (s = 0: sinc's guard) or 1e-13 rad/s from it: the same numbers."""
    rng = np.random.default_rng(7)
    x = states(rng, 33)
    us, dts = samples(rng, 40)
    x[:, 13:16] = x[0, 13:16]
    us[:, 3:6] = x[0, 13:16] + (0.0 if rate == "zero" else 1e-13 * rng.normal(size=(40, 3)))
    got = ins_batch.integrate_inputs(x, us, dts, G_COL, trapezoidal)
    ref = integrate_reference(x, us, dts, G_COL, trapezoidal)
    assert_blockwise_close(got, ref)
    if rate == "zero":
        assert np.array_equal(got[:, 6:10], x[:, 6:10])    # q (x) 1 = q exactly


@needs_kernel
@pytest.mark.parametrize("q_scale", [0.5, 1.7])
def test_integrate_non_unit_quaternions(q_scale):
    """|q| != 1 (renormalize: false): the rotation is by q / |q| (divided by |q|^2), q_k = q_0 (x) P_k."""
    rng = np.random.default_rng(11)
    x = states(rng, 33, q_scale=q_scale)
    us, dts = samples(rng, 40)
    for trap in (True, False):
        assert_blockwise_close(ins_batch.integrate_inputs(x, us, dts, G_COL, trap),
                               integrate_reference(x, us, dts, G_COL, trap))


@needs_kernel
def test_integrate_leading_axes_and_layouts():
    """States (16,), (2, 3, 16) and a non-contiguous (N, 16) slice (the Gauss-Markov model's INS part): the
    numpy shapes, the same numbers; the inputs are not modified."""
    rng = np.random.default_rng(3)
    us, dts = samples(rng, 40)
    x17 = np.concatenate([states(rng, 6), rng.normal(size=(6, 1))], axis=1)
    for x in (x17[0, :16], x17[:, :16].reshape(2, 3, 16), x17[:, :16]):
        before = x.copy()
        got = ins_batch.integrate_inputs(x, us, dts, G_COL, True)
        ref = integrate_reference(x, us, dts, G_COL, True)
        assert got.shape == ref.shape == x.shape
        assert_blockwise_close(got.reshape(-1, 16), ref.reshape(-1, 16))
        assert np.array_equal(x, before)
    with pytest.raises(ValueError, match=r"\(\.\.\., 16\)"):
        ins_batch.integrate_inputs(np.zeros((2, 8)), us, dts, G_COL, True)


@needs_kernel
def test_integrate_time_sums_are_numpys_bit_for_bit():
    """T and sum of the position weights as numpy's pairwise sums (k > 8 uses 8 accumulators, k > 129
    splits): with zero states, v_k = g T and p_k = g sum w_j exactly as numpy forms them."""
    for k in (3, 9, 40, 130, 300):
        dts = np.random.default_rng(k).uniform(0.001, 0.1, k)
        us = np.zeros((k, 6))
        x = np.zeros(16)
        x[6] = 1.0
        got = ins_batch.integrate_inputs(x, us, dts, G_COL, False)
        T = float(dts.sum())
        w1 = dts * (T - np.cumsum(dts))
        assert got[3:6].tolist() == (G_COL[:, 0] * T).tolist()
        assert got[0:3].tolist() == (G_COL[:, 0] * w1.sum()).tolist()


@needs_kernel
@pytest.mark.parametrize("qnv", [0.0, 1e-12])
@pytest.mark.parametrize("k", [1, 2, 40, 100])
def test_interval_noise_matches_numpy(k, qnv):
    rng = np.random.default_rng(k)
    x0 = states(rng, 1)[0]
    x1 = x0 + 0.1 * rng.normal(size=16)
    _, dts = samples(rng, k)
    var = [np.full(3, v) for v in (4e-6, 3.4e-7, 1e-8, 1.4e-10)]
    qc = np.concatenate([np.zeros(3), *var])
    g = G_COL[:, 0]
    got = ins_batch.interval_noise(x0, x1, dts, g, *var, qc, qnv)
    ref = ins_batch.interval_noise_numpy(x0, x1, dts, g, *var, qc, qnv)
    assert np.array_equal(got, got.T)
    d = np.sqrt(np.diag(ref))
    assert np.all(np.abs(got - ref) <= 1e-12 * np.outer(d, d))     # relative to the correlation scale


def test_interval_noise_non_isotropic_is_the_numpy_code():
    rng = np.random.default_rng(5)
    x0 = states(rng, 1)[0]
    x1 = x0 + 0.1 * rng.normal(size=16)
    dts = np.full(40, 0.01)
    var = [np.array([4e-6, 5e-6, 6e-6]), np.full(3, 3.4e-7), np.full(3, 1e-8), np.full(3, 1.4e-10)]
    args = (x0, x1, dts, G_COL[:, 0], *var, None, 1e-12)
    assert np.array_equal(ins_batch.interval_noise(*args), ins_batch.interval_noise_numpy(*args))


# ---------------------------------------------------------------------------------------- bad arguments
def _integrate_args():
    return dict(x=np.zeros((33, 16)), us=np.zeros((40, 6)), dts=np.full(40, 0.01), g=np.zeros(3), trapezoidal=True,
                out=np.empty((33, 16)))


@needs_kernel
@pytest.mark.parametrize("name, value, error, match", [
    ("x", [[0.0] * 16], TypeError, "x must be a float64 array"),
    ("x", np.zeros((33, 16), dtype=np.float32), TypeError, "x must be float64"),
    ("x", np.zeros((33, 15)), ValueError, "x: axis 1 has length 15, expected 16"),
    ("x", np.zeros(16), ValueError, "x must have 2 dimension"),
    ("x", np.zeros((16, 33)).T, ValueError, "x must be C-contiguous"),
    ("x", np.zeros((33, 32))[:, ::2], ValueError, "x must be C-contiguous"),
    ("us", np.zeros((40, 6), order="F"), ValueError, "us must be C-contiguous"),
    ("us", np.zeros((40, 7)), ValueError, "us: axis 1"),
    ("dts", np.full(39, 0.01), ValueError, "dts: axis 0 has length 39, expected 40"),
    ("dts", np.full(40, 1, dtype=np.int64), TypeError, "dts must be float64"),
    ("g", np.zeros((3, 1)), ValueError, "g must have 1 dimension"),
    ("out", np.empty((32, 16)), ValueError, "out: axis 0 has length 32, expected 33"),
    ("out", np.empty((33, 16))[::-1], ValueError, "out must be C-contiguous"),
    ("out", bytes(33 * 16 * 8), ValueError, "out must be a writable"),
    ("out", None, TypeError, "out must be a float64 array"),
])
def test_integrate_bad_arguments_raise(name, value, error, match):
    args = _integrate_args()
    args[name] = value
    with pytest.raises(error, match=match):
        K.integrate(*args.values())


@needs_kernel
def test_integrate_refuses_read_only_and_overlapping_out():
    args = _integrate_args()
    ro = np.empty((33, 16))
    ro.flags.writeable = False
    with pytest.raises(ValueError, match="out must be a writable"):
        K.integrate(*{**args, "out": ro}.values())
    big = np.zeros(33 * 16)                                # us and out in one buffer
    with pytest.raises(ValueError, match="must not overlap"):
        K.integrate(args["x"], big[:240].reshape(40, 6), args["dts"], args["g"], True, big.reshape(33, 16))
    with pytest.raises(ValueError, match="must not overlap"):           # x partly out
        K.integrate(big[16:].reshape(32, 16), args["us"], args["dts"], args["g"], True, big[:-16].reshape(32, 16))
    with pytest.raises(TypeError):
        K.integrate(*list(args.values())[:5])
    rng = np.random.default_rng(0)
    x = rng.normal(size=(33, 16))                          # out may be x itself
    us, dts, g = rng.normal(size=(40, 6)), args["dts"], rng.normal(size=3)
    ref = np.empty((33, 16))
    K.integrate(x, us, dts, g, True, ref)
    K.integrate(x, us, dts, g, True, x)
    assert np.array_equal(x, ref)


@needs_kernel
def test_integrate_trapezoidal_flag_errors_propagate():
    class Bad:
        def __bool__(self):
            raise RuntimeError("no truth value")
    args = _integrate_args()
    with pytest.raises(RuntimeError, match="no truth value"):
        K.integrate(*{**args, "trapezoidal": Bad()}.values())


@needs_kernel
def test_integrate_empty_runs_and_points():
    """k = 0 samples: the states unchanged; N = 0 points: nothing written."""
    rng = np.random.default_rng(2)
    x = states(rng, 4)
    out = np.empty((4, 16))
    K.integrate(x, np.zeros((0, 6)), np.zeros(0), np.ones(3), True, out)
    assert np.array_equal(out, x)
    K.integrate(np.zeros((0, 16)), np.zeros((3, 6)), np.full(3, 0.01), np.ones(3), False, np.empty((0, 16)))


@needs_kernel
def test_interval_noise_bad_arguments_raise():
    x = np.zeros(16)
    x[6] = 1.0
    good = [x, x, np.full(4, 0.01), np.zeros(3), np.ones(15), 0.0, np.empty((16, 16))]

    def call(i, value):
        args = list(good)
        args[i] = value
        return K.interval_noise(*args)
    with pytest.raises(ValueError, match="x1: axis 0 has length 17"):
        call(1, np.zeros(17))
    with pytest.raises(TypeError, match="qc must be float64"):
        call(4, np.ones(15, dtype=np.float32))
    with pytest.raises(ValueError, match="out must have 2 dimension"):
        call(6, np.empty(256))
    with pytest.raises(ValueError, match="at least one sample"):
        call(2, np.zeros(0))
    with pytest.raises(ValueError, match="finite T > 0"):
        call(2, np.zeros(3))
    with pytest.raises(TypeError):
        call(5, "a")
    buf = np.zeros(256 + 16)                               # x0 is the last row of out
    with pytest.raises(ValueError, match="out must not overlap x0"):
        K.interval_noise(buf[256:], x, good[2], good[3], good[4], 0.0, buf.reshape(17, 16)[1:])


# ---------------------------------------------------------------------------------------- a whole run
def _run_estimates(tmp_path: Path, pure: bool) -> list[list[str]]:
    out = tmp_path / f"{'pure' if pure else 'kernel'}.csv"
    env = {**os.environ, "FUSION_PURE_PYTHON": "1" if pure else "0"}
    subprocess.run([sys.executable, "-m", "fusion.cli", "run", str(ROOT / "configs" / "abps_ins.yaml"), "-q",
                    "-o", str(out)], cwd=ROOT, env=env, check=True, capture_output=True)
    return list(csv.reader(out.open()))


@needs_kernel
def test_abps_ins_run_same_estimates_with_and_without_the_kernel(tmp_path):
    """`fusion run configs/abps_ins.yaml` with the kernel and with FUSION_PURE_PYTHON=1: the same rows,
    times, reasons and sensors, every state and sd to 1e-9 relative (measured: 7e-14 absolute)."""
    pure, kern = _run_estimates(tmp_path, True), _run_estimates(tmp_path, False)
    assert pure[0] == kern[0] and len(pure) == len(kern) > 300
    head = pure[0]
    num = [i for i, h in enumerate(head) if h not in ("t", "reason", "sensor")]
    for a, b in zip(pure[1:], kern[1:]):
        assert [a[i] for i, h in enumerate(head) if i not in num] == [b[i] for i, h in enumerate(head) if i not in num]
    A = np.array([[float(r[i]) for i in num] for r in pure[1:]])
    B = np.array([[float(r[i]) for i in num] for r in kern[1:]])
    assert not np.array_equal(A, B)                       # the kernel did run (the last bits move)
    np.testing.assert_allclose(B, A, rtol=1e-9, atol=1e-12)


# ---------------------------------------------------------------------------------------- input_from's checks
@needs_kernel
def test_imu_ok_accepts_only_six_finite_floats_within_the_limits():
    ok = (0.1, -0.2, -9.8, 0.01, 0.02, -0.03)
    assert K.imu_ok(ok, 49.0, 5.24) is True
    assert K.imu_ok(ok, math.inf, math.inf) is True
    assert K.imu_ok(ok, 9.8, 0.03) is True                   # the limits are inclusive
    for bad in (list(ok), ok[:5], ok + (0.0,), (1, *ok[1:]), (np.float64(0.1), *ok[1:]), ("0.1", *ok[1:]),
                (math.nan, *ok[1:]), (*ok[:5], math.inf), (*ok[:5], -math.inf)):
        assert K.imu_ok(bad, 49.0, 5.24) is False, bad
    assert K.imu_ok(ok, 9.7, 5.24) is False                  # |az| beyond max_f
    assert K.imu_ok(ok, 49.0, 0.029) is False                # |gz| beyond max_w
    with pytest.raises(TypeError):
        K.imu_ok(ok, None, 5.24)
    with pytest.raises(TypeError):
        K.imu_ok(ok, 49.0)


@needs_kernel
@pytest.mark.parametrize("values", [
    (0.1, -0.2, -9.8, 0.01, 0.02, -0.03), (1, 2, 3, 0, 0, 0), (np.float64(0.1), 0.0, -9.8, 0.0, 0.0, 0.0),
    (0.1, 0.2), (0.1, -0.2, -9.8, 0.01, 0.02, math.nan), (60.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    (0.0, 0.0, 0.0, 6.0, 0.0, 0.0), ("x", 0.0, 0.0, 0.0, 0.0, 0.0), [0.1, -0.2, -9.8, 0.01, 0.02, -0.03],
])
def test_input_from_is_the_same_with_and_without_the_kernel(values, monkeypatch):
    """The fast path changes nothing: the same array, or the same exception and message."""
    from fusion import testing
    from fusion.api import Message
    from fusion_plugins.process import ins as ins_module
    proc = testing.build("process", "ins", {"max_specific_force": 49.0, "max_rate": 5.24})

    def outcome():
        try:
            u = proc.input_from(Message(1.0, "imu", values))
            return u.dtype, u.tolist()
        except Exception as exc:   # noqa: BLE001 - the outcome compared is the exception itself
            return type(exc), str(exc)
    with_kernel = outcome()
    monkeypatch.setattr(ins_module, "_KERNEL", None)
    assert outcome() == with_kernel
