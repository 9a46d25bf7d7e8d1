"""The models' batched methods (pv Q/F, range H, ins Q) equal the single-state ones state by state, and
the fallbacks of fusion.batch.models (one call per filter, batched central differences) do too."""
from __future__ import annotations

import numpy as np
import pytest

from fusion import testing
from fusion.batch.models import batch_F, batch_H, batch_Q, numerical_jacobian_batch
from fusion_plugins.filters.jacobian import numerical_jacobian

from .conftest import bound_range


@pytest.mark.parametrize("kw", [{}, {"gyro_noise_density": (5e-4, 6e-4, 7e-4)}, {"quat_norm_variance": 1e-6},
                                {"hold_after": 0.005}])
def test_ins_Q_batch(kw):
    proc = testing.build("process", "ins", kw)
    rng = np.random.default_rng(2)
    x = np.zeros((6, 16))
    q = rng.normal(size=(6, 4))
    x[:, 6:10] = q / np.linalg.norm(q, axis=1, keepdims=True) * rng.uniform(0.9, 1.1, (6, 1))
    u = np.array([0.1, 0.0, -9.8, 0.01, 0.02, 0.0])
    Qb = batch_Q(proc, x, u, 0.01)
    assert Qb.shape == (6, 16, 16)
    for i in range(6):
        np.testing.assert_allclose(Qb[i], proc.Q(x[i], u, 0.01), rtol=1e-14, atol=1e-20)


def test_range_jacobian_batch_and_pv(uwb):
    model = bound_range(uwb, "B3")
    x = np.random.default_rng(3).normal(10.0, 5.0, (7, 4))
    H = batch_H(model, x)
    assert H.shape == (7, 1, 4)
    for i in range(7):
        np.testing.assert_array_equal(H[i], model.jacobian(x[i]))
    proc = uwb.process
    np.testing.assert_array_equal(np.broadcast_to(batch_F(proc, x, None, 0.05), (7, 4, 4))[3], proc.jacobian(x[3], None, 0.05))
    np.testing.assert_array_equal(np.broadcast_to(batch_Q(proc, x, None, 0.05), (7, 4, 4))[5], proc.Q(x[5], None, 0.05))


def test_numerical_jacobian_batch_equals_single():
    proc = testing.build("process", "ins")
    rng = np.random.default_rng(4)
    x = np.zeros((3, 16))
    x[:, 6] = 1.0
    x[:, :6] = rng.normal(size=(3, 6))
    u = np.array([0.1, 0.0, -9.8, 0.01, 0.02, 0.0])
    J = numerical_jacobian_batch(lambda X: proc.f(X, u, 0.01), x)
    for i in range(3):
        np.testing.assert_allclose(J[i], numerical_jacobian(lambda X: proc.f(X, u, 0.01), x[i]), rtol=1e-12, atol=1e-12)
