"""An independent strapdown reference for the simulator tests (no code shared with fusion.simulate): the
IMU samples are interpolated by quintic splines and the NED strapdown equations

    p' = v,   v' = C_b^n(q) f_b + [0, 0, g],   q' = q (x) [0, w_b] / 2

are integrated by classical fourth-order Runge-Kutta at half the sample interval (the simulator builds its
truth from Euler angles with scipy's Rotation; here the attitude is a quaternion ODE)."""
from __future__ import annotations

import numpy as np
from scipy.interpolate import make_interp_spline


def _omega(w: np.ndarray) -> np.ndarray:
    """4x4 matrix of q (x) [0, w] (scalar-first Hamilton product, w in the body frame)."""
    x, y, z = w
    return np.array([[0.0, -x, -y, -z], [x, 0.0, z, -y], [y, -z, 0.0, x], [z, y, -x, 0.0]])


def _dcm(q: np.ndarray) -> np.ndarray:
    """C_b^n of a unit scalar-first quaternion."""
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def strapdown(t: np.ndarray, f_b: np.ndarray, w_b: np.ndarray, p0, v0, q0, g: float, t_end: float,
              substeps: int = 2):
    """Integrate from t[0] to t_end (a multiple of the step); returns (p, v, q) at the end."""
    fs = make_interp_spline(t, f_b, k=5)
    ws = make_interp_spline(t, w_b, k=5)
    h = (t[1] - t[0]) / substeps
    n = int(round((t_end - t[0]) / h))
    nodes = t[0] + 0.5 * h * np.arange(2 * n + 1)        # every half step: RK4 stage times
    F, W = fs(nodes), ws(nodes)
    gn = np.array([0.0, 0.0, g])
    p, v, q = np.array(p0, float), np.array(v0, float), np.array(q0, float)

    def deriv(q, v, k):
        R = _dcm(q / np.sqrt(q @ q))
        return 0.5 * _omega(W[k]) @ q, R @ F[k] + gn, v

    for i in range(n):
        k0, k1, k2 = 2 * i, 2 * i + 1, 2 * i + 2
        dq1, dv1, dp1 = deriv(q, v, k0)
        dq2, dv2, dp2 = deriv(q + 0.5 * h * dq1, v + 0.5 * h * dv1, k1)
        dq3, dv3, dp3 = deriv(q + 0.5 * h * dq2, v + 0.5 * h * dv2, k1)
        dq4, dv4, dp4 = deriv(q + h * dq3, v + h * dv3, k2)
        q = q + h / 6 * (dq1 + 2 * dq2 + 2 * dq3 + dq4)
        v = v + h / 6 * (dv1 + 2 * dv2 + 2 * dv3 + dv4)
        p = p + h / 6 * (dp1 + 2 * dp2 + 2 * dp3 + dp4)
        q = q / np.linalg.norm(q)
    return p, v, q
