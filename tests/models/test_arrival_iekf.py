"""firing_clock (eq. 10) and arrival_time (eq. 11): transition and noise over n firings against the
step-by-step product, Jacobians against finite differences; the IEKF's update at the MAP point of a
strongly non-linear single firing (scipy least squares as the reference)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from fusion import testing
from fusion.api import Belief, BuildContext, ConfigError, MalformedMessage, Message

LAB = {"B1": [0, 0, 0], "B2": [2.6, 0, 0], "B3": [0, 2.6, 0], "B4": [0, 0, 2.6]}
C = 340.0


def _clock(**params):
    return testing.build("process", "firing_clock", params)


def _arrival(**params):
    proc = _clock()
    ctx = BuildContext(layout=proc.layout, beacons={k: np.array(v, float) for k, v in LAB.items()}, sensor="us")
    return testing.build("measurement", "arrival_time", params, ctx)


def test_layout_and_one_firing_is_eq_10():
    proc = _clock(position_sd=[0.01, 0.02, 0.03], period_sd=1e-6)
    assert proc.layout.names == ("px", "py", "pz", "Tx", "tx")   # size-1 vector blocks get the x suffix (fusion.api)
    x = np.array([1.0, 2.0, 0.5, 0.225, 10.0])
    Phi = np.eye(5)
    Phi[4, 3] = 1.0
    for dt in (0.225, 0.214, 0.236):                      # T +- (d_j - d_i) / c
        assert np.allclose(proc.f(x, None, dt), Phi @ x)
        assert np.allclose(proc.jacobian(x, None, dt), Phi)
        assert np.allclose(proc.Q(x, None, dt), np.diag([1e-4, 4e-4, 9e-4, 1e-12, 0.0]))
    assert np.allclose(proc.f(x, None, 0.0), x) and not proc.Q(x, None, 0.0).any()


@pytest.mark.parametrize("n", [2, 3, 5])
def test_n_firings_is_n_steps(n):
    """A missed pulse: the state and noise over n firings are n steps of eq. 10 (sum Phi^k Q Phi^kT)."""
    proc = _clock(position_sd=0.004, period_sd=3e-6, clock_sd=2e-6)
    x = np.array([1.0, 2.0, 0.5, 0.225, 10.0])
    Phi, Q1 = proc.jacobian(x, None, 0.225), proc.Q(x, None, 0.225)
    ref_x, ref_Q = x.copy(), np.zeros((5, 5))
    for _ in range(n):
        ref_x, ref_Q = Phi @ ref_x, Phi @ ref_Q @ Phi.T + Q1
    dt = n * 0.225 + 0.007
    assert np.allclose(proc.f(x, None, dt), ref_x, rtol=0, atol=1e-12)
    assert np.allclose(proc.Q(x, None, dt), ref_Q, rtol=1e-12, atol=1e-24)
    assert testing.check_process_jacobian(proc, x, None, dt) < 1e-6


def test_vectorised():
    proc, model = _clock(), _arrival()
    X = np.random.default_rng(0).uniform(0.2, 2.5, (7, 5))
    X[:, 3] = 0.225
    assert testing.check_process_vectorised(proc, X, None, 0.23) < 1e-12
    bound = model.observe(Message(1.0, "us", ("B3", 1.0, 4.0))).model
    assert testing.check_measurement_vectorised(bound, X) < 1e-12


def test_arrival_time_is_eq_11_and_its_jacobian():
    model = _arrival()
    obs = model.observe(Message(3.2, "us", ("B2", 3.2001, 17.0)))
    assert obs.z.tolist() == [3.2001]
    x = np.array([1.1, 0.7, 1.9, 0.225, 3.19])
    d = np.linalg.norm(x[:3] - np.array(LAB["B2"]))
    assert obs.model.h(x)[0] == pytest.approx(3.19 + d / C, rel=1e-14)
    assert testing.check_measurement_jacobian(obs.model, x) < 1e-6


def test_arrival_time_bad_input():
    model = _arrival()
    with pytest.raises(MalformedMessage, match="unknown beacon"):
        model.observe(Message(1.0, "us", ("B7", 1.0, 2.0)))
    with pytest.raises(MalformedMessage):
        model.observe(Message(1.0, "us", ("B1",)))
    with pytest.raises(ConfigError, match="firing time"):
        testing.build("measurement", "arrival_time", {}, BuildContext(layout=testing.build("process", "pv", {"dims": 3}).layout,
                                                                       beacons={"B1": np.zeros(3)}))


@pytest.mark.parametrize("seed", range(4))
def test_iekf_update_is_the_map_point_of_a_nonlinear_firing(seed):
    """One arrival from a beacon 0.3 m away, the prior long (0.3 m sd) at 45 deg to the line of sight and
    short (2-5 cm) across: over the prior the arrival time is a strongly curved function of the position. The
    IEKF's fixed point minimises |x - x^-|^2_P^-1 + |z - h(x)|^2_R^-1; the EKF's one step does not."""
    rng = np.random.default_rng(seed)
    model = _arrival()
    b = np.array(LAB["B1"], float)
    e1 = rng.normal(size=3)
    e1 /= np.linalg.norm(e1)
    E, _ = np.linalg.qr(np.c_[e1, rng.normal(size=(3, 2))])       # e1 (line of sight), e2, e3
    x_prior = np.r_[b + 0.3 * E[:, 0], 0.225, 5.0]
    A = np.c_[(E[:, 0] + E[:, 1]) / np.sqrt(2), (E[:, 0] - E[:, 1]) / np.sqrt(2), E[:, 2]]
    Pp = A @ np.diag([0.3, 0.02, 0.05]) ** 2 @ A.T
    P = np.zeros((5, 5))
    P[:3, :3], P[3, 3], P[4, 4] = Pp, 1e-10, 1e-10                # t known to 10 us: the position must move
    x_true = x_prior.copy()
    x_true[:3] += (0.25 + 0.1 * seed) * A[:, 0]     # 0.8-1.8 sd along the long axis, away from the beacon
    obs = model.observe(Message(5.0, "us", ("B1", float(model._bind("B1").h(x_true)[0]) + 1e-4, 1.0)))
    R = np.array([[(2e-4) ** 2]])
    iekf = testing.build("filter", "iekf", {"max_iterations": 50, "tolerance": 1e-13})
    ekf = testing.build("filter", "ekf", {})
    belief = Belief(5.0, x_prior, P=P)
    res = iekf.update(belief, obs.model, obs.z, R)
    Lp = np.linalg.cholesky(P)

    def whitened(x):
        return np.r_[np.linalg.solve(Lp, x - x_prior), (obs.z - obs.model.h(x)) / np.sqrt(R[0, 0])]

    ref = least_squares(whitened, res.belief.x, xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    cost = lambda x: float(whitened(x) @ whitened(x))                       # noqa: E731
    # also from the prior (a second, independent start of the reference)
    ref2 = least_squares(whitened, x_prior, xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    best = ref if cost(ref) <= cost(ref2) else ref2
    assert cost(res.belief.x) <= cost(best) * (1 + 1e-8) + 1e-12      # the reference's ftol, with margin
    # Two solvers agree as far as the conditioning and the reference's stopping rule allow: far below the
    # posterior sd (1e-4 of it is the same answer), whatever the reference's last digits.
    sd = np.sqrt(np.diag(res.belief.P)[:3])
    assert np.all(np.abs(res.belief.x[:3] - best[:3]) < 1e-4 * sd)
    e = ekf.update(belief, obs.model, obs.z, R).belief.x
    assert np.abs(e[:3] - best[:3]).max() > 0.01           # the single linearisation is off the MAP point
