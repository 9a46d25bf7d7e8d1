"""The batched UKF against FilterPy's UnscentedKalmanFilter (MerweScaledSigmaPoints), one FilterPy filter
per batch member, on the 4-beacon range model of fusion.testing (m = 4: the batch's general update path)
and a model without batched Q or Jacobian methods (the per-filter fallbacks)."""
from __future__ import annotations

import numpy as np
import pytest

import filterpy.kalman as filterpy_kalman  # the test extra

from fusion import testing
from fusion.batch import make_batch_filter

BEACONS = [[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0]]


@pytest.mark.parametrize("linear_prediction", ["never", "auto"])
@pytest.mark.parametrize("name", ["ukf", "srukf"])
def test_batched_ukf_equals_filterpy(name, linear_prediction):
    rng = np.random.default_rng(5)
    proc = testing.ConstantVelocity()
    meas = testing.RangeMeasurement(testing.RangeMeasurement.Params(beacons=BEACONS))
    R = np.eye(4) * 0.1 ** 2
    N = 4
    x0 = np.array([5.5, 3.5, 0.0, 0.0]) + rng.normal(0, 0.5, (N, 4))
    P0 = np.diag([1.0, 1.0, 0.5, 0.5])
    refs = []
    for i in range(N):
        pts = filterpy_kalman.MerweScaledSigmaPoints(4, alpha=0.5, beta=2.0, kappa=0.0)
        ref = filterpy_kalman.UnscentedKalmanFilter(4, 4, 0.1, meas.h, lambda x, dt: proc.f(x, None, dt), pts)
        ref.x, ref.P, ref.Q, ref.R = x0[i].copy(), P0.copy(), proc.Q(x0[i], None, 0.1), R
        refs.append(ref)
    bf = make_batch_filter(testing.build("filter", name, {"linear_prediction": linear_prediction}))
    b = bf.initial_belief(0.0, x0, P0)
    truth = np.array([5.0, 4.0, 1.0, 0.5])
    worst = 0.0
    for _ in range(150):
        truth = proc.f(truth, None, 0.1)
        z = meas.h(truth) + rng.normal(0.0, 0.1, (N, 4))
        b = bf.predict(b, proc, None, 0.1)
        up = bf.update(b, meas, z, R)
        b = up.belief
        for i, ref in enumerate(refs):
            ref.predict()
            ref.update(z[i])
            worst = max(worst, np.abs(b.x[i] - ref.x).max(), np.abs(b.cov[i] - ref.P).max(),
                        np.abs(up.S[i] - ref.S).max())
            # closed-form equations both, differing only by rounding (no solver tolerance): measured under 1 %
            # of these tolerances with numpy 1.26 and 2.4, FilterPy 2.0
            assert up.nis[i] == pytest.approx(float(ref.y @ np.linalg.solve(ref.S, ref.y)), rel=1e-9)
    assert worst < 1e-9
