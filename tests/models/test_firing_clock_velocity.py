"""firing_clock ``motion: constant_velocity`` (tester5 finding 4): the velocity block after the clock, the
transition p + v dt and the white-acceleration noise against Van Loan's integral of the continuous model;
vectorised over sigma points; the attitude and direction-error blocks keep working behind it; the random
walk stays the default (layout and numbers unchanged)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from fusion import testing
from fusion.api import BuildContext

LAB = {"B1": [0, 0, 0], "B2": [2.6, 0, 0], "B3": [0, 2.6, 0], "B4": [0, 0, 2.6]}


def _clock(**params):
    ctx = BuildContext(beacons={k: np.array(v, float) for k, v in LAB.items()})
    return testing.build("process", "firing_clock", params, ctx)


def _van_loan_pv(q: np.ndarray, dt: float) -> np.ndarray:
    """Q (6, 6) of p' = v, v' = w, Cov w = diag(q) delta: the integral of e^{As} G q G^T e^{A^T s} over dt."""
    A = np.zeros((6, 6))
    A[:3, 3:] = np.eye(3)
    Qc = np.zeros((6, 6))
    Qc[3:, 3:] = np.diag(q)
    M = expm(np.block([[-A, Qc], [np.zeros((6, 6)), A.T]]) * dt)
    return M[6:, 6:].T @ M[:6, 6:]


def test_default_is_the_papers_random_walk():
    proc = _clock()
    assert proc.params.motion == "random_walk" and proc.layout.names == ("px", "py", "pz", "Tx", "tx")


@pytest.mark.parametrize("dt", [0.225, 0.214, 2 * 0.225 + 0.01])
def test_constant_velocity_is_the_pv_discretisation(dt):
    q = np.array([1e-4, 4e-4, 2e-5])
    proc = _clock(motion="constant_velocity", acceleration_psd=q.tolist(), position_sd=0.0, period_sd=1e-6)
    assert proc.layout.names == ("px", "py", "pz", "Tx", "tx", "vx", "vy", "vz")
    x = np.array([1.0, 2.0, 0.5, 0.225, 10.0, 0.02, -0.01, 0.005])
    n = np.rint(dt / 0.225)
    want = x.copy()
    want[:3] += x[5:] * dt
    want[4] += n * 0.225
    assert np.allclose(proc.f(x, None, dt), want, rtol=0, atol=1e-15)
    assert testing.check_process_jacobian(proc, x, None, dt) < 1e-6
    Q = proc.Q(x, None, dt)
    pv = np.r_[0:3, 5:8]
    # expm (Pade with scaling and squaring) is accurate to a few eps on this nilpotent ||A dt|| < 1 block; the
    # closed form and Van Loan agree to 2e-16 relative: 1e-9 is room for any LAPACK, not a digit of one
    assert np.allclose(Q[np.ix_(pv, pv)], _van_loan_pv(q, dt), rtol=1e-9, atol=1e-20)
    assert not Q[np.ix_(pv, [3, 4])].any()                    # the clock's noise is its own
    # the random walk of position_sd adds n sd^2 per axis to the position on top
    Q2 = _clock(motion="constant_velocity", acceleration_psd=q.tolist(), position_sd=0.003, period_sd=1e-6).Q(x, None, dt)
    assert np.allclose(Q2 - Q, np.diag([n * 9e-6] * 3 + [0.0] * 5), rtol=1e-12, atol=1e-20)


def test_constant_velocity_vectorised_and_at_zero_dt():
    proc = _clock(motion="constant_velocity")
    X = np.random.default_rng(1).uniform(-0.05, 2.5, (9, 8))
    X[:, 3] = 0.225
    assert testing.check_process_vectorised(proc, X, None, 0.23) < 1e-12
    assert np.array_equal(proc.f(X[0], None, 0.0), X[0]) and not proc.Q(X[0], None, 0.0).any()


def test_velocity_ahead_of_attitude_and_direction_errors():
    """With the attitude (and the direction-error blocks) the velocity sits before q: the attitude's noise
    and the errors' coupling go to q's rows wherever it is."""
    rw = _clock(attitude_sd_deg=0.8, direction_error_sd_deg=10.0)
    cv = _clock(attitude_sd_deg=0.8, direction_error_sd_deg=10.0, motion="constant_velocity")
    assert cv.layout["v"] == slice(5, 8) and cv.layout["q"] == slice(8, 12) and cv.n == rw.n + 3
    x_rw = np.zeros(rw.n)
    x_rw[:5] = [1.0, 1.2, 1.4, 0.225, 3.0]
    x_rw[5:9] = [0.9, 0.1, -0.2, 0.3]
    x_rw[5:9] /= np.linalg.norm(x_rw[5:9])
    x_cv = np.insert(x_rw, 5, [0.0, 0.0, 0.0])
    keep = np.r_[0:5, 8:cv.n]                                   # cv's elements that rw has
    Q_rw, Q_cv = rw.Q(x_rw, None, 0.225), cv.Q(x_cv, None, 0.225)
    extra = np.zeros(len(keep))
    extra[:3] = 1e-4 * 0.225 ** 3 / 3                           # the white acceleration's share of the position
    assert np.allclose(Q_cv[np.ix_(keep, keep)], Q_rw + np.diag(extra), rtol=1e-12, atol=1e-18)
    assert np.allclose(cv.f(x_cv, None, 0.225)[keep], rw.f(x_rw, None, 0.225), atol=1e-15)
    assert np.allclose(cv.jacobian(x_cv, None, 0.225)[np.ix_(keep, keep)], rw.jacobian(x_rw, None, 0.225))


def test_bad_acceleration_psd_is_refused():
    from fusion.api import ConfigError
    with pytest.raises((ValueError, ConfigError), match="acceleration_psd"):
        _clock(motion="constant_velocity", acceleration_psd=[1e-4, -1.0, 0.0])


def test_acceleration_psd_without_constant_velocity_is_refused():
    """A density that the random walk would silently ignore: refused, naming both keys."""
    with pytest.raises(ValueError, match="acceleration_psd.*constant_velocity"):
        _clock(acceleration_psd=1e-4)
