"""Measurement ``position`` (paper 000 eq. 53): lever arm, Jacobian, vectorisation, 2-D, fix covariance."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion import quaternion as quat
from fusion.api import BuildContext, ConfigError, MalformedMessage, Message, StateLayout
from fusion_plugins.measurement.position import Position, PositionParams, static_R
from fusion_plugins.solvers.ols_trilateration import pack_fix

INS = StateLayout.parse("p:3 v:3 q:4:quaternion ba:3 bw:3")
PV2 = StateLayout.parse("p:2 v:2")
ARM = (0.4, -0.2, -0.6)


def model(layout=INS, **kw) -> Position:
    return Position(PositionParams(**kw), BuildContext(layout=layout))


def random_states(rng, n):
    X = rng.normal(size=(n, 16))
    X[:, 6:10] *= rng.uniform(0.9, 1.1, (n, 1)) / np.linalg.norm(X[:, 6:10], axis=1, keepdims=True)
    return X


def test_registered():
    from fusion.registry import default_registry

    assert default_registry().get("measurement", "position") is Position


def test_lever_arm_rotates_with_attitude_like_scipy():
    m = model(lever_arm=ARM)
    rng = np.random.default_rng(0)
    for rot in Rotation.random(20, random_state=1):
        x = np.zeros(16)
        x[0:3] = rng.normal(size=3)
        x[6:10] = rot.as_quat(scalar_first=True)
        np.testing.assert_allclose(m.h(x), x[0:3] + rot.apply(ARM), atol=1e-14)
    # known attitudes: yaw +90 deg turns body forward (x) into east (y); roll 180 deg flips down to up
    x = np.zeros(16)
    x[6:10] = quat.from_euler(0.0, 0.0, np.pi / 2)
    np.testing.assert_allclose(m.h(x), [0.2, 0.4, -0.6], atol=1e-15)
    x[6:10] = quat.from_euler(np.pi, 0.0, 0.0)
    np.testing.assert_allclose(m.h(x), [0.4, 0.2, 0.6], atol=1e-15)


def test_h_vectorised_equals_row_by_row_and_ignores_norm():
    rng = np.random.default_rng(2)
    m = model(lever_arm=ARM)
    X = random_states(rng, 33).reshape(3, 11, 16)
    Z = m.h(X)
    assert Z.shape == (3, 11, 3)
    np.testing.assert_allclose(Z, np.array([[m.h(x) for x in row] for row in X]), atol=1e-15)
    x = X[0, 0].copy()
    y = x.copy()
    y[6:10] *= 1.3
    np.testing.assert_allclose(m.h(x), m.h(y), atol=1e-14)


@pytest.mark.parametrize("kw,layout", [({"lever_arm": ARM}, INS), ({}, INS), ({"lever_arm": ARM, "dim": 2}, INS),
                                       ({}, PV2)])
def test_jacobian_matches_finite_differences(kw, layout):
    rng = np.random.default_rng(4)
    m = model(layout, **kw)
    x = random_states(rng, 1)[0] if layout is INS else rng.normal(size=layout.n)
    h = 1e-6
    Hn = np.array([(m.h(x + h * e) - m.h(x - h * e)) / (2 * h) for e in np.eye(layout.n)]).T
    H = m.jacobian(x)
    assert H.shape == (m.dim, layout.n)
    np.testing.assert_allclose(H, Hn, atol=1e-8)


def test_two_d_state():
    m = model(PV2)
    assert m.dim == 2
    np.testing.assert_array_equal(m.h(np.array([[1.0, 2.0, 3.0, 4.0]])), [[1.0, 2.0]])
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        m = model(PV2, lever_arm=ARM)                           # no attitude: lever arm ignored, said so
    assert any("lever_arm ignored" in str(x.message) for x in w) and "ignored" in m.note
    np.testing.assert_array_equal(m.h(np.array([1.0, 2.0, 3.0, 4.0])), [1.0, 2.0])


def test_horizontal_fix_on_3d_state():
    m = model(dim=2, lever_arm=ARM)
    x = np.zeros(16)
    x[6] = 1.0
    np.testing.assert_allclose(m.h(x), [0.4, -0.2])


def test_layout_validation():
    with pytest.raises(ConfigError, match="position block 'p'"):
        model(StateLayout.parse("x:2 v:2"))
    with pytest.raises(ConfigError, match="position block 'p'"):
        Position(PositionParams(), BuildContext())
    with pytest.raises(ConfigError, match="dim 3"):
        model(PV2, dim=3)


def test_observe_plain_and_with_covariance():
    m = model(lever_arm=ARM)
    obs = m.observe(Message(1.5, "gps", (1.0, 2.0, 3.0)))
    assert obs.t == 1.5 and obs.R is None and obs.model is m
    np.testing.assert_array_equal(obs.z, [1.0, 2.0, 3.0])
    cov = np.array([[0.01, 0.002, 0.0], [0.002, 0.02, 0.0], [0.0, 0.0, 0.09]])
    obs = m.observe(Message(2.0, "abps", pack_fix(np.array([4.0, 5.0, 6.0]), cov)))
    np.testing.assert_array_equal(obs.z, [4.0, 5.0, 6.0])
    np.testing.assert_allclose(obs.R, cov)
    obs = model(PV2).observe(Message(2.0, "abps", pack_fix(np.array([4.0, 5.0, 6.0]), cov)))
    np.testing.assert_array_equal(obs.z, [4.0, 5.0])
    np.testing.assert_allclose(obs.R, cov[:2, :2])
    obs = model(use_fix_covariance=False).observe(Message(2.0, "abps", pack_fix(np.zeros(3), cov)))
    assert obs.R is None
    for bad in [(1.0, 2.0), (1.0, float("nan"), 3.0), (1.0,) * 5, ("a", 1.0, 2.0)]:
        with pytest.raises(MalformedMessage):
            m.observe(Message(0.0, "abps", bad))


def test_static_R():
    rng = np.random.default_rng(9)
    fixes = rng.normal([1.0, 2.0, 0.0], [0.05, 0.1, 0.2], size=(4000, 3))
    R = static_R(fixes)
    np.testing.assert_allclose(np.sqrt(np.diag(R)), [0.05, 0.1, 0.2], rtol=0.05)
    assert np.count_nonzero(R - np.diag(np.diag(R))) == 0
    assert static_R(fixes, full=True).shape == (3, 3)


def test_contract_checks():
    from fusion import testing

    for layout, kw in ((INS, {"lever_arm": ARM}), (PV2, {})):
        m = model(layout, **kw)
        X = testing.random_states(layout, 9, seed=3)
        testing.check_measurement_vectorised(m, X)
        testing.check_measurement_jacobian(m, X[0])


def test_position_from_inverts_h():
    m = model(lever_arm=ARM)
    x = random_states(np.random.default_rng(5), 1)[0]
    z = np.array([3.0, -1.0, 0.5])
    x[0:3] = m.position_from(z, x)
    np.testing.assert_allclose(m.h(x), z, atol=1e-14)
    np.testing.assert_array_equal(model(PV2).position_from(z, np.zeros(4)), z[:2])


def test_a_typed_fix_with_a_non_finite_covariance_is_malformed():
    """np.linalg.cholesky does not raise on NaN: the covariance is checked for finiteness first, so a solver's
    NaN covariance never reaches the filter as R."""
    from fusion.api import Fix

    m = model()
    good = np.diag([0.01, 0.02, 0.09])
    assert np.allclose(m.observe(Fix(1.0, np.array([1.0, 2.0, 3.0]), good)).R, good)
    for bad in (np.full((3, 3), np.nan), np.diag([0.01, np.inf, 0.09]), np.diag([0.01, -0.02, 0.09])):
        with pytest.raises(MalformedMessage, match="covariance"):
            m.observe(Fix(1.0, np.array([1.0, 2.0, 3.0]), bad))


def test_offset_block_must_be_an_error_block_not_one_the_model_measures():
    """offset_block adds a state block to the fix; naming p, v or q would add the position (or velocity,
    attitude) to itself: a wiring error, not a silent 27 m error."""
    lay = StateLayout.parse("p:3 v:3 q:4:quaternion ba:3 bw:3 hz:1")
    assert model(lay, offset_block="hz", offset_axes=(2,))._off == slice(16, 17)
    for bad in ("p", "v"):
        with pytest.raises(ConfigError, match="already measures"):
            model(lay, offset_block=bad, offset_axes=(0, 1, 2))
    with pytest.raises(ConfigError, match="attitude block"):         # with a lever arm, q is measured too
        model(lay, lever_arm=ARM, offset_block="q")
