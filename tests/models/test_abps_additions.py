"""Additions for the ABPS/INS system (issue 5): a fix with an age (the position model's ``p - v age``), the INS hold noise over an IMU gap, the pivoted-Cholesky row square root."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from fusion import testing
from fusion.api import BuildContext, ConfigError, MalformedMessage, Message, StateLayout
from fusion_plugins.filters.linalg import psd_sqrt_rows
from fusion_plugins.measurement.position import AgedPosition, Position, PositionParams
from fusion_plugins.solvers.ols_trilateration import OlsParams, OlsTrilateration, pack_fix, unpack_fix

INS = StateLayout.parse("p:3 v:3 q:4:quaternion ba:3 bw:3")
MINE = np.array([[0.0, 0.1, -0.9], [5.0, 2.9, -0.9], [10.0, 0.1, -0.9], [15.0, 2.9, -0.9]])


def test_fix_with_age_is_predicted_through_the_velocity():
    m = Position(PositionParams(lever_arm=(0.2, 0.0, -0.4)), BuildContext(layout=INS))
    cov = np.diag([0.01, 0.02, 0.09])
    obs = m.observe(Message(3.0, "abps", pack_fix(np.array([4.0, 5.0, 6.0]), cov) + (0.15,)))
    assert isinstance(obs.model, AgedPosition) and obs.model.age == 0.15 and obs.t == 3.0
    np.testing.assert_allclose(obs.R, cov)
    X = testing.random_states(INS, 7, seed=4)
    np.testing.assert_allclose(obs.model.h(X), m.h(X) - 0.15 * X[:, 3:6], atol=1e-15)
    testing.check_measurement_vectorised(obs.model, X)
    testing.check_measurement_jacobian(obs.model, X[0])
    np.testing.assert_allclose(obs.model.h(np.r_[obs.model.position_from(obs.z, X[0]), X[0, 3:]]), obs.z, atol=1e-12)
    assert m.observe(Message(3.0, "abps", pack_fix(np.zeros(3), cov) + (0.0,))).model is m
    with pytest.raises(MalformedMessage, match="negative"):
        m.observe(Message(3.0, "abps", pack_fix(np.zeros(3), cov) + (-0.1,)))
    pv = Position(PositionParams(), BuildContext(layout=StateLayout.parse("p:3")))
    with pytest.raises(MalformedMessage, match="velocity"):
        pv.observe(Message(3.0, "abps", pack_fix(np.zeros(3), cov) + (0.1,)))


def _gm(sd, tau, e):
    """Variance of the integral of a Gauss-Markov process over e (closed form, independent of the code)."""
    x = e / tau
    return 2 * sd * sd * tau * tau * (x - 1 + np.exp(-x))


def test_ins_hold_noise_grows_only_past_hold_after():
    base = testing.build("process", "ins", {})
    held = testing.build("process", "ins", {"hold_after": 0.015, "hold_accel_sd": 0.5, "hold_yaw_rate_sd": 0.5,
                                            "hold_tilt_rate_sd": 0.02, "hold_motion_tau": 2.0})
    x = INS.vector({"q": [1, 0, 0, 0]})
    u = np.r_[0, 0, -9.8, 0, 0, 0]
    np.testing.assert_array_equal(held.Q(x, u, 0.01), base.Q(x, u, 0.01))
    d = held.Q(x, u, 0.02) - base.Q(x, u, 0.02)                  # one dropped sample: negligible
    assert 0 < d[3, 3] < 1e-5 and d[3, 3] == pytest.approx(_gm(0.5, 2.0, 0.005))
    d = held.Q(x, u, 1.015) - base.Q(x, u, 1.015)                # a 1 s gap: v sd 0.46 m/s
    pp = quad(lambda t: 2 * 0.25 * 2.0 * (1 - np.exp(-t / 2.0)) * (1.0 - t) ** 2, 0.0, 1.0)[0]   # p sd 0.19 m
    # quad's default tolerance is 1.5e-8 relative and it estimates its error on this smooth integrand at 1e-14
    # of the value: rel 1e-6 is 70 times the tolerance asked for (the closed form against closed form: rounding)
    assert d[3, 3] == pytest.approx(_gm(0.5, 2.0, 1.0)) and d[0, 0] == pytest.approx(pp, rel=1e-6)
    assert np.linalg.eigvalsh(held.Q(x, u, 1.015)).min() > -1e-15
    dts = np.r_[np.full(5, 0.01), 1.015, np.full(5, 0.01)]
    us = np.tile(u, (11, 1))
    x1 = held.normalize(held.f_inputs(x, us, dts))
    dQ = held.Q_inputs(x, x1, us, dts) - base.Q_inputs(x, x1, us, dts)
    assert dQ[3, 3] == pytest.approx(_gm(0.5, 2.0, 1.0))


@pytest.mark.parametrize("rank", [16, 15, 9, 1])
def test_psd_sqrt_rows_of_singular_matrices(rank):
    rng = np.random.default_rng(rank)
    A = rng.normal(size=(rank, 16))
    Q = A.T @ A
    B = psd_sqrt_rows(Q)
    np.testing.assert_allclose(B.T @ B, Q, atol=1e-12 * np.abs(Q).max())
