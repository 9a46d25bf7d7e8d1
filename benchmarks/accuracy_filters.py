"""Agreement of the square-root UKF with the UKF, and of both with an extended-precision UKF, against
alpha (the numbers of benchmarks/README.md "Exactness").

    python benchmarks/accuracy_filters.py

Model: 4-state constant velocity + ranges to 4 beacons (the benchmark's), 300 seeded steps, sigma-point
prediction (linear_prediction: never) so that every step goes through the unscented transform. The
reference runs the same UKF in numpy's long double (80-bit on x86: 64-bit mantissa) with its own
Cholesky and elimination, so it shares no code with the filters.
"""
from __future__ import annotations

import numpy as np

from fusion import testing

LD = np.longdouble
BEACONS = [[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0]]


def problem(steps=300, seed=5):
    rng = np.random.default_rng(seed)
    proc = testing.ConstantVelocity(testing.ConstantVelocity.Params(q=0.5))
    meas = testing.RangeMeasurement(testing.RangeMeasurement.Params(beacons=BEACONS))
    x, zs = np.array([5.0, 4.0, 1.0, 0.5]), []
    for _ in range(steps):
        x = proc.f(x, None, 0.1) + rng.multivariate_normal(np.zeros(4), proc.Q(x, None, 0.1))
        zs.append(meas.h(x) + rng.normal(0.0, 0.1, 4))
    return proc, meas, np.array([5.5, 3.5, 0.0, 0.0]), np.diag([1.0, 1.0, 0.5, 0.5]), np.eye(4) * 0.01, zs


def run(flt, proc, meas, x0, P0, R, zs):
    b, out = flt.initial_belief(0.0, x0, P0), []
    for z in zs:
        b = flt.update(flt.predict(b, proc, None, 0.1), meas, z, R).belief
        out.append((b.x, b.cov))
    return out


def _chol(P):
    n = P.shape[0]
    L = np.zeros_like(P)
    for j in range(n):
        L[j, j] = np.sqrt(P[j, j] - (L[j, :j] ** 2).sum())
        for i in range(j + 1, n):
            L[i, j] = (P[i, j] - (L[i, :j] * L[j, :j]).sum()) / L[j, j]
    return L


def reference_ukf(proc, meas, x0, P0, R, zs, alpha, beta=2.0, kappa=0.0):
    """The UKF of plugins/filters/ukf.py (sigma-point prediction), in long double."""
    n = 4
    lam = LD(alpha) ** 2 * (n + kappa) - n
    c = n + lam
    Wm = np.full(2 * n + 1, 1 / (2 * c), dtype=LD)
    Wm[0] = lam / c
    Wc = Wm.copy()
    Wc[0] += 1 - LD(alpha) ** 2 + beta
    F, Q = proc.F(0.1).astype(LD), proc.Q(None, None, 0.1).astype(LD)
    B, RL, eta = meas.beacons.astype(LD), R.astype(LD), np.sqrt(c)
    x, P, out = x0.astype(LD), P0.astype(LD), []
    for z in zs:
        L = _chol(P)
        Y = np.vstack([x, x + eta * L.T, x - eta * L.T]) @ F.T
        x = Wm @ Y
        P = ((Y - x).T * Wc) @ (Y - x) + Q
        L = _chol(P)
        X = np.vstack([x, x + eta * L.T, x - eta * L.T])
        d = X[:, None, :2] - B[None]
        Z = np.sqrt((d * d).sum(-1))
        zm = Wm @ Z
        Pzz = ((Z - zm).T * Wc) @ (Z - zm) + RL
        Pxz = ((X - x).T * Wc) @ (Z - zm)
        Ly = _chol(Pzz)
        W = np.stack([_solve_lower(Ly, Pxz[i]) for i in range(n)], axis=1)   # Ly^-1 Pxz^T
        w = _solve_lower(Ly, z.astype(LD) - zm)
        x = x + W.T @ w
        P = P - W.T @ W
        out.append((x, P))
    return out


def _solve_lower(L, b):
    x = np.zeros_like(b)
    for i in range(len(b)):
        x[i] = (b[i] - (L[i, :i] * x[:i]).sum()) / L[i, i]
    return x


def max_rel(a, b, k):
    return max(float(np.max(np.abs(np.asarray(p[k], float) - np.asarray(q[k], float))
                            / np.maximum(1.0, np.abs(np.asarray(q[k], float))))) for p, q in zip(a, b))


def main():
    proc, meas, x0, P0, R, zs = problem()
    print("max relative difference over 300 steps (x | P); reference: long-double UKF")
    print(f"{'alpha':>6s}  {'srukf(recentred) vs ukf':>24s}  {'srukf(cholupdate) vs ukf':>24s}  "
          f"{'ukf vs ref':>20s}  {'srukf(recentred) vs ref':>24s}  {'srukf(cholupdate) vs ref':>24s}")
    for alpha in (1e-3, 1e-2, 0.1, 0.5, 1.0):
        common = {"alpha": alpha, "linear_prediction": "never"}
        u = run(testing.build("filter", "ukf", common), proc, meas, x0, P0, R, zs)
        r = run(testing.build("filter", "srukf", {**common, "zeroth_point": "recentred"}), proc, meas, x0, P0, R, zs)
        c = run(testing.build("filter", "srukf", {**common, "zeroth_point": "cholupdate"}), proc, meas, x0, P0, R, zs)
        ref = reference_ukf(proc, meas, x0, P0, R, zs, alpha)
        cells = [(r, u), (c, u), (u, ref), (r, ref), (c, ref)]
        print(f"{alpha:6g}  " + "  ".join(f"{max_rel(a, b, 0):10.1e} | {max_rel(a, b, 1):8.1e}".rjust(24 if i != 2 else 20)
                                           for i, (a, b) in enumerate(cells)))


if __name__ == "__main__":
    main()
