"""The filter contract: exact on a linear-Gaussian problem, the interface every filter honours."""
from __future__ import annotations

import numpy as np

from fusion.api import UpdateResult

from .numeric import worst as _worst
from .reference import ConstantVelocity, PositionMeasurement, RejectAll, reference_kf

__all__ = ["check_filter_linear_exactness", "check_filter_interface"]


# --------------------------------------------------------------------------- filter contracts
def _linear_problem(steps: int, seed: int, dims: int = 2):
    rng = np.random.default_rng(seed)
    proc = ConstantVelocity(ConstantVelocity.Params(dims=dims, q=0.5))
    meas = PositionMeasurement(PositionMeasurement.Params(dim=dims, n=2 * dims))
    n = 2 * dims
    x0 = rng.standard_normal(n)
    P0 = np.diag(rng.uniform(0.5, 2.0, n))
    R = np.diag(rng.uniform(0.01, 0.1, dims))
    truth = x0 + rng.multivariate_normal(np.zeros(n), P0)
    seq = []
    for _ in range(steps):
        dt = float(rng.uniform(0.05, 0.2))
        truth = proc.f(truth, None, dt) + rng.multivariate_normal(np.zeros(n), proc.Q(truth, None, dt))
        z = meas.h(truth) + rng.multivariate_normal(np.zeros(dims), R)
        seq.append((dt, z))
    return proc, meas, x0, P0, R, seq


def check_filter_linear_exactness(flt, steps: int = 200, seed: int = 0, tol: float = 1e-9) -> float:
    """On a linear-Gaussian model (constant velocity + position) the filter must equal the textbook
    Kalman filter to ``tol`` (relative where values exceed 1) at every step, in x and P.

    Also checks the interface at each step: predict advances t by dt and returns a new belief; the
    input belief's arrays are never mutated; the covariance stays symmetric; update reports the
    innovation, its covariance and the NIS of the reference filter."""
    proc, meas, x0, P0, R, seq = _linear_problem(steps, seed)
    ref = reference_kf(x0, P0, ((proc.F(dt), proc.Q(None, None, dt), meas.H, R, z) for dt, z in seq))
    b = flt.initial_belief(0.0, x0, P0)
    worst = 0.0
    for k, ((dt, z), (xr, Pr)) in enumerate(zip(seq, ref)):
        x_before, cov_before = b.x.copy(), b.cov.copy()
        prior = flt.predict(b, proc, None, dt)
        assert prior is not b, f"{flt!r}: predict must return a new belief"
        assert abs(prior.t - (b.t + dt)) < 1e-12, f"{flt!r}: predict moved t to {prior.t}, expected {b.t + dt}"
        res = flt.update(prior, meas, z, R)
        assert isinstance(res, UpdateResult) and res.accepted, f"{flt!r}: update did not accept"
        assert np.array_equal(b.x, x_before) and np.array_equal(b.cov, cov_before), \
            f"{flt!r}: predict/update mutated its input belief"
        b = res.belief
        P = b.cov
        e = max(_worst(b.x, xr), _worst(P, Pr))
        worst = max(worst, e)
        assert e <= tol, f"{flt!r}: step {k}: differs from the textbook KF by {e:.3g} (> {tol:g})"
        assert _worst(P, P.T) <= 1e-12, f"{flt!r}: step {k}: covariance not symmetric"
        # innovation statistics against the prior
        Pp = prior.cov
        S = meas.H @ Pp @ meas.H.T + R
        y = z - meas.h(prior.x)
        e2 = max(_worst(res.innovation, y), _worst(res.S, S),
                 abs(res.nis - float(y @ np.linalg.solve(S, y))) / max(1.0, res.nis))
        assert e2 <= max(tol, 1e-8), f"{flt!r}: step {k}: innovation/S/NIS differ by {e2:.3g}"
    return worst


def check_filter_interface(flt) -> None:
    """A rejected update (gate says no) returns the input belief untouched, accepted False, with the
    innovation and NIS still reported; an update at the same time keeps t."""
    proc, meas, x0, P0, R, seq = _linear_problem(3, 1)
    b = flt.predict(flt.initial_belief(0.0, x0, P0), proc, None, seq[0][0])
    res = flt.update(b, meas, seq[0][1], R, gate=RejectAll())
    assert res.accepted is False, f"{flt!r}: gate rejected but accepted is {res.accepted}"
    assert res.belief is b, f"{flt!r}: a rejected update must return the input belief"
    assert np.isfinite(res.nis) and res.nis > 0.0, f"{flt!r}: NIS not reported on rejection"
    assert res.innovation.shape == (meas.dim,) and res.S.shape == (meas.dim, meas.dim)
    res = flt.update(b, meas, seq[0][1], R)
    assert res.belief.t == b.t, f"{flt!r}: update changed t"
