"""The RTS smoothers against independent references: a batch information-form least-squares solution
(linear-Gaussian), FilterPy's ``rts_smoother`` (KF, EKF about the filtered means, UKF), and square-root
== covariance form; the composition of a run of inputs == the same samples one node each."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import cho_factor, cho_solve

from fusion import testing
from smoothing_models import Swing, Unicycle, UnicycleRunNoise, cov, smooth_sequence

import filterpy.kalman as filterpy_kalman  # the test extra: a missing one is a failure, not a skip

DT = 0.1
BEACONS = [[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0]]


def _linear_steps(seed, N=60, skip=(7, 8, 20)):
    """CV model, position measurements at every step except ``skip`` (prediction-only nodes)."""
    rng = np.random.default_rng(seed)
    proc = testing.ConstantVelocity(testing.ConstantVelocity.Params(q=0.7))
    meas = testing.PositionMeasurement()
    R = np.diag([0.04, 0.09])
    x = np.array([5.0, 4.0, 1.0, -0.5])
    steps, zs = [], []
    for k in range(1, N + 1):
        x = proc.f(x, None, DT) + rng.multivariate_normal(np.zeros(4), proc.Q(x, None, DT))
        steps.append(("predict", (None, DT)))
        z = meas.h(x) + rng.normal(0.0, [0.2, 0.3])
        zs.append(None if k in skip else z)
        if k not in skip:
            steps.append(("update", (meas, z, R)))
    return proc, meas, R, steps, zs


def _batch_information(proc, meas, R, zs, x0, P0):
    """MAP of all states x_0..x_N at once: minimise |x_0 - m0|^2_P0^-1 + sum |x_k - F x_{k-1}|^2_Q^-1
    + sum |z_k - H x_k|^2_R^-1. Normal equations Lambda X = eta (block tridiagonal Lambda), solved by
    Cholesky; the covariance blocks are those of Lambda^-1."""
    n, N = len(x0), len(zs)
    F, Q = proc.F(DT), proc.Q(None, None, DT)
    H = meas.jacobian(np.zeros(n))
    Qi, Ri, P0i = (cho_solve(cho_factor(M), np.eye(M.shape[0])) for M in (Q, R, P0))
    Lam = np.zeros(((N + 1) * n,) * 2)
    eta = np.zeros((N + 1) * n)
    blk = lambda k: slice(k * n, (k + 1) * n)
    Lam[blk(0), blk(0)] += P0i
    eta[blk(0)] += P0i @ x0
    for k in range(1, N + 1):
        A = np.hstack([-F, np.eye(n)])      # x_k - F x_{k-1}
        idx = np.r_[blk(k - 1).start:blk(k).stop]
        Lam[np.ix_(idx, idx)] += A.T @ Qi @ A
        if zs[k - 1] is not None:
            Lam[blk(k), blk(k)] += H.T @ Ri @ H
            eta[blk(k)] += H.T @ Ri @ zs[k - 1]
    c = cho_factor(Lam)
    X = cho_solve(c, eta).reshape(N + 1, n)
    Cov = cho_solve(c, np.eye(len(eta)))
    return X, [Cov[blk(k), blk(k)] for k in range(N + 1)]


@pytest.mark.parametrize("name", ["kf", "ekf", "iekf", "ukf", "srukf"])
@pytest.mark.parametrize("seed", [1, 2])
def test_linear_gaussian_equals_batch_least_squares(name, seed):
    proc, meas, R, steps, zs = _linear_steps(seed)
    x0, P0 = np.array([5.5, 3.5, 0.0, 0.0]), np.diag([1.0, 1.0, 0.5, 0.5])
    params = {"alpha": 0.5} if name in ("ukf", "srukf") else {}
    _, smoothed, _ = smooth_sequence(testing.build("filter", name, params), proc, steps, x0, P0)
    X, C = _batch_information(proc, meas, R, zs, x0, P0)
    # one estimate per step: the node of state k is the last estimate before the (k+1)-th predict
    node_est = []
    for i, (kind, _) in enumerate(steps):
        if kind == "predict" and i > 0:
            node_est.append(i)          # estimate index i = after step i-1 (index 0 is the initial)
    node_est = [0] + node_est + [len(steps)]
    assert len(node_est) == len(X)
    for k, i in enumerate(node_est):
        # the batch solution is one dense solve, the smoother a recursion: both exact for a linear-Gaussian
        # model, apart by rounding (states and covariances of order 1); 1e-9 is > 600x the largest measured
        assert np.abs(smoothed[i].x - X[k]).max() < 1e-9
        assert np.abs(cov(smoothed[i]) - C[k]).max() < 1e-9


def test_kf_equals_filterpy_rts():
    proc, meas, R, steps, zs = _linear_steps(3, skip=())
    x0, P0 = np.array([5.5, 3.5, 0.0, 0.0]), np.diag([1.0, 1.0, 0.5, 0.5])
    filtered, smoothed, _ = smooth_sequence(testing.build("filter", "kf"), proc, steps, x0, P0)
    ref = filterpy_kalman.KalmanFilter(4, 2)
    ref.x, ref.P, ref.F, ref.Q, ref.R = x0.copy(), P0.copy(), proc.F(DT), proc.Q(None, None, DT), R
    ref.H = meas.jacobian(x0)
    Xs, Ps, _, _ = ref.batch_filter(zs)
    xs, ps, _, _ = ref.rts_smoother(Xs, Ps)
    ours = smoothed[2::2]                      # after each update
    # FilterPy's batch_filter and rts_smoother are closed form too: rounding apart, > 600x below 1e-9
    assert np.abs(np.array([b.x for b in filtered[2::2]]) - Xs).max() < 1e-9
    assert np.abs(np.array([b.x for b in ours]) - xs).max() < 1e-9
    assert np.abs(np.array([cov(b) for b in ours]) - ps).max() < 1e-9


def _swing_steps(seed, N=80):
    rng = np.random.default_rng(seed)
    proc = Swing()
    meas = testing.RangeMeasurement(testing.RangeMeasurement.Params(beacons=[[0.0, 3.0], [2.0, -1.0]], n=2))
    R = np.eye(2) * 0.05 ** 2
    x = np.array([1.0, 0.0])
    steps, zs = [], []
    for _ in range(N):
        x = proc.f(x, None, DT) + rng.multivariate_normal(np.zeros(2), proc.Q(x, None, DT))
        z = meas.h(x) + rng.normal(0.0, 0.05, 2)
        steps += [("predict", (None, DT)), ("update", (meas, z, R))]
        zs.append(z)
    return proc, meas, R, steps, zs


def test_ekf_equals_textbook_extended_rts():
    """EKF-RTS (Saerkkae 2013, Bayesian Filtering and Smoothing, alg. 9.3) written out here with
    np.linalg.solve, from our filtered means and covariances: F_k = df/dx at the filtered mean x_k,
    m^- = f(x_k), P^- = F P F^T + Q, G = P F^T (P^-)^-1."""
    proc, meas, R, steps, _ = _swing_steps(4)
    x0, P0 = np.array([0.8, 0.1]), np.diag([0.2, 0.2])
    filtered, smoothed, _ = smooth_sequence(testing.build("filter", "ekf"), proc, steps, x0, P0)
    nodes = [0] + list(range(2, len(filtered), 2))
    ms, Ps = filtered[nodes[-1]].x, filtered[nodes[-1]].P
    ref = [(ms, Ps)]
    for i in reversed(nodes[:-1]):
        m, P = filtered[i].x, filtered[i].P
        F = proc.jacobian(m, None, DT)
        mp, Pp = proc.f(m, None, DT), F @ P @ F.T + proc.Q(m, None, DT)
        G = np.linalg.solve(Pp.T, (P @ F.T).T).T
        ms, Ps = m + G @ (ms - mp), P + G @ (Ps - Pp) @ G.T
        ref.append((ms, Ps))
    ref.reverse()
    for i, (m, P) in zip(nodes, ref):
        assert np.abs(smoothed[i].x - m).max() < 1e-9
        assert np.abs(cov(smoothed[i]) - P).max() < 1e-9
    # and the linear-model case is FilterPy's KalmanFilter.rts_smoother: test_kf_equals_filterpy_rts


@pytest.mark.parametrize("alpha,beta,kappa", [(0.5, 2.0, 0.0), (1.0, 2.0, 1.0)])
def test_ukf_equals_filterpy_unscented_rts(alpha, beta, kappa):
    proc, meas, R, steps, zs = _swing_steps(5)
    x0, P0 = np.array([0.8, 0.1]), np.diag([0.2, 0.2])
    flt = testing.build("filter", "ukf", {"alpha": alpha, "beta": beta, "kappa": kappa})
    filtered, smoothed, _ = smooth_sequence(flt, proc, steps, x0, P0)
    pts = filterpy_kalman.MerweScaledSigmaPoints(2, alpha=alpha, beta=beta, kappa=kappa)
    ref = filterpy_kalman.UnscentedKalmanFilter(2, 2, DT, meas.h, lambda x, dt: proc.f(x, None, dt), pts)
    ref.x, ref.P, ref.Q, ref.R = x0.copy(), P0.copy(), proc.Q(x0, None, DT), R
    Xs, Ps = ref.batch_filter(zs)
    xs, ps, _ = ref.rts_smoother(Xs, Ps)
    ours = smoothed[2::2]
    # the unscented filter and smoother are closed form in FilterPy and here: rounding apart, > 600x below 1e-9
    assert np.abs(np.array([b.x for b in filtered[2::2]]) - Xs).max() < 1e-9
    assert np.abs(np.array([b.x for b in ours]) - xs).max() < 1e-9
    assert np.abs(np.array([cov(b) for b in ours]) - ps).max() < 1e-9


def _unicycle_steps(seed, N=30, k=5, batched=True, cls=Unicycle):
    """Runs of ``k`` input samples between range updates (``inputs``), or the same samples one
    ``predict`` each (a node per sample)."""
    rng = np.random.default_rng(seed)
    proc = cls()
    meas = testing.RangeMeasurement(testing.RangeMeasurement.Params(beacons=BEACONS, n=3))
    R = np.eye(4) * 0.1 ** 2
    x = np.array([3.0, 2.0, 0.3])
    steps = []
    for _ in range(N):
        us = np.column_stack([1.0 + 0.2 * rng.standard_normal(k), 0.3 * rng.standard_normal(k)])
        dts = np.full(k, 0.02) + 0.005 * rng.random(k)
        for u, dt in zip(us, dts):
            x = proc.f(x, u, dt) + rng.multivariate_normal(np.zeros(3), proc.Q(x, u, dt))
        if batched:
            steps.append(("inputs", (us, dts)))
        else:
            steps += [("predict", (u, float(dt))) for u, dt in zip(us, dts)]
        steps.append(("update", (meas, meas.h(x[:2]) + rng.normal(0.0, 0.1, 4), R)))
    return proc, steps


def _at_updates(steps, beliefs):
    return [beliefs[i + 1] for i, (kind, _) in enumerate(steps) if kind == "update"]


@pytest.mark.parametrize("name,params", [("ekf", {}), ("ukf", {"batch_inputs": False}),
                                         ("srukf", {"batch_inputs": False}), ("ukf", {}), ("srukf", {})])
def test_run_of_inputs_composes_exactly(name, params):
    """A run of k samples in one predict_inputs (one recorded transition, composed gains) smooths to
    the same numbers as the samples predicted one node each. Also with batch_inputs (the default): the
    unicycle has no Q_inputs, so the sigma-point filters predict it sample by sample and the recorder
    composes the per-sample transitions (tester4 #7)."""
    x0, P0 = np.array([3.0, 2.0, 0.3]), np.diag([0.3, 0.3, 0.1])
    proc, steps_b = _unicycle_steps(6, batched=True)
    _, steps_s = _unicycle_steps(6, batched=False)
    _, sm_b, _ = smooth_sequence(testing.build("filter", name, params), proc, steps_b, x0, P0)
    _, sm_s, _ = smooth_sequence(testing.build("filter", name, params), proc, steps_s, x0, P0)
    a, b = _at_updates(steps_b, sm_b), _at_updates(steps_s, sm_s)
    assert np.abs(np.array([e.x for e in a]) - np.array([e.x for e in b])).max() < 1e-10
    assert np.abs(np.array([cov(e) for e in a]) - np.array([cov(e) for e in b])).max() < 1e-10


@pytest.mark.parametrize("problem", ["swing", "unicycle_batched", "unicycle_samples", "unicycle_run_noise"])
def test_square_root_equals_covariance_form(problem):
    """unicycle_batched: runs of inputs the filters predict sample by sample (no Q_inputs), recorded as
    composed per-sample transitions; unicycle_run_noise: the same runs with Q_inputs, one sigma-point
    step (and one recorded transition) a run."""
    if problem == "swing":
        proc, _, _, steps, _ = _swing_steps(7)
        x0, P0 = np.array([0.8, 0.1]), np.diag([0.2, 0.2])
    else:
        proc, steps = _unicycle_steps(8, batched=problem != "unicycle_samples",
                                      cls=UnicycleRunNoise if problem == "unicycle_run_noise" else Unicycle)
        x0, P0 = np.array([3.0, 2.0, 0.3]), np.diag([0.3, 0.3, 0.1])
    for zeroth in ("recentred", "cholupdate"):
        _, sm_u, _ = smooth_sequence(testing.build("filter", "ukf", {"alpha": 0.5}), proc, steps, x0, P0)
        sr = testing.build("filter", "srukf", {"alpha": 0.5, "zeroth_point": zeroth})
        _, sm_s, _ = smooth_sequence(sr, proc, steps, x0, P0)
        assert all(b.P is None and b.S is not None for b in sm_s)          # square root throughout
        assert np.abs(np.array([b.x for b in sm_u]) - np.array([b.x for b in sm_s])).max() < 1e-9
        assert np.abs(np.array([cov(b) for b in sm_u]) - np.array([cov(b) for b in sm_s])).max() < 1e-9


def test_disk_store_gives_the_same_numbers():
    proc, meas, R, steps, _ = _linear_steps(9, N=200)
    x0, P0 = np.array([5.5, 3.5, 0.0, 0.0]), np.diag([1.0, 1.0, 0.5, 0.5])
    _, mem, on_disk0 = smooth_sequence(testing.build("filter", "ekf"), proc, steps, x0, P0, disk=False)
    _, dsk, on_disk1 = smooth_sequence(testing.build("filter", "ekf"), proc, steps, x0, P0, chunk=16, disk=True)
    assert on_disk0 == 0 and on_disk1 > 0
    for a, b in zip(mem, dsk):
        assert np.array_equal(a.x, b.x) and np.array_equal(a.P, b.P)


def test_smoothed_nees_is_chi_square_over_seeds():
    """Linear-Gaussian: the smoothed belief is the exact posterior, so its NEES against the true states
    averages the state dimension (4) within the 99.9% interval of the mean of 50 x 61 chi2(4) values."""
    from scipy.stats import chi2

    total, count, better = 0.0, 0, 0
    for seed in range(50):
        rng = np.random.default_rng(1000 + seed)
        proc = testing.ConstantVelocity(testing.ConstantVelocity.Params(q=0.7))
        meas = testing.PositionMeasurement()
        R = np.diag([0.04, 0.09])
        x0, P0 = np.array([5.5, 3.5, 0.0, 0.0]), np.diag([1.0, 1.0, 0.5, 0.5])
        x = rng.multivariate_normal(x0, P0)
        truth, steps = [x], []
        for _ in range(60):
            x = proc.f(x, None, DT) + rng.multivariate_normal(np.zeros(4), proc.Q(x, None, DT))
            truth.append(x)
            steps += [("predict", (None, DT)), ("update", (meas, meas.h(x) + rng.normal(0.0, [0.2, 0.3]), R))]
        filtered, smoothed, _ = smooth_sequence(testing.build("filter", "kf"), proc, steps, x0, P0)
        sm = [smoothed[0]] + smoothed[2::2]
        fi = [filtered[0]] + filtered[2::2]
        for xt, b in zip(truth, sm):
            total += testing.nees(xt, b)
            count += 1
        err = lambda bs: np.mean([(b.x[:2] - xt[:2]) @ (b.x[:2] - xt[:2]) for xt, b in zip(truth, bs)])
        better += err(sm) < err(fi)
    lo, hi = chi2.ppf([0.0005, 0.9995], 4 * count) / count
    assert lo < total / count < hi
    assert better >= 45          # smoothed position MSE below the filtered one on (nearly) every seed


def test_a_filter_declares_its_smoother_or_gets_one_clear_error():
    from fusion.api import ConfigError, Filter
    from fusion_plugins.filters.rts import RtsBackend, SqrtRtsBackend, backend_for

    class Plain(Filter):
        name = "plain"

    class Own(Plain):
        def rts_backend(self):
            return "mine"

    with pytest.raises(ConfigError, match="no Rauch-Tung-Striebel smoother"):
        backend_for(Plain())
    assert backend_for(Own()) == "mine"
    assert type(backend_for(testing.build("filter", "srukf"))) is SqrtRtsBackend
    assert type(backend_for(testing.build("filter", "iekf"))) is RtsBackend
