"""Contract tests for plugin authors, and small reference models.

Run the same checks the built-ins pass on your own component::

    import pytest
    from fusion import testing

    @testing.parametrize_registered("filter")          # every registered filter, yours included
    def test_filter_reduces_to_kf(name):
        testing.check_filter_linear_exactness(testing.build("filter", name))

    def test_my_process():
        proc = MyProcess()
        x = testing.random_states(proc.layout, 7)
        testing.check_process_vectorised(proc, x, u=None, dt=0.1)
        testing.check_process_jacobian(proc, x[0], u=None, dt=0.1)

Every ``check_*`` raises AssertionError with the worst mismatch, and returns it when it passes.
Importing this module does not import pytest (only :func:`parametrize_registered` does).

Reference models (test-only, not registered): :class:`ConstantVelocity` (linear, paper 001 eq. 4),
:class:`PositionMeasurement` (linear) and :class:`RangeMeasurement` (ranges to fixed beacons, paper
001 eq. 6). :func:`reference_kf` is a textbook Kalman filter written independently of the plugins.
"""
from __future__ import annotations

from typing import Any, Iterable

import numpy as np
from pydantic import Field

from fusion.api import (Belief, BuildContext, Component, Gate, MeasurementModel, Params, ProcessModel,
                        StateLayout, UpdateResult)

__all__ = [
    "ConstantVelocity", "PositionMeasurement", "RangeMeasurement", "RejectAll", "reference_kf",
    "registered", "build", "parametrize_registered", "random_states", "nees",
    "check_filter_linear_exactness", "check_filter_interface", "check_process_vectorised",
    "check_process_jacobian", "check_measurement_vectorised", "check_measurement_jacobian",
]


# --------------------------------------------------------------------------- reference models
class ConstantVelocity(ProcessModel):
    """Constant velocity in ``dims`` axes, state ``p:dims v:dims`` (m, m/s), white-acceleration noise
    of spectral density ``q`` (m^2/s^3) per axis (paper 001 eqs. 3-4)::

        p' = p + v dt,  v' = v,   Q_axis = q [[dt^3/3, dt^2/2], [dt^2/2, dt]]

    ``analytic_jacobian: false`` makes ``jacobian`` return None (exercises numerical fallbacks)."""

    name = "test_cv"
    linear = True

    class Params(Params):
        dims: int = Field(2, ge=1, le=3)
        q: float = Field(0.5, ge=0.0, description="acceleration spectral density, m^2/s^3")
        analytic_jacobian: bool = True

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        d = self.params.dims
        self.layout = StateLayout.parse(f"p:{d} v:{d}")
        self.d = d
        self._cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def _matrices(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        m = self._cache.get(dt)
        if m is None:
            d, q = self.d, self.params.q
            F = np.eye(2 * d)
            F[:d, d:] = dt * np.eye(d)
            I = np.eye(d)
            Q = q * np.block([[dt ** 3 / 3 * I, dt ** 2 / 2 * I], [dt ** 2 / 2 * I, dt * I]])
            F.flags.writeable = Q.flags.writeable = False
            if len(self._cache) > 256:
                self._cache.clear()
            m = self._cache[dt] = (F, Q)
        return m

    def F(self, dt: float) -> np.ndarray:
        """The transition matrix (read-only, cached per dt)."""
        return self._matrices(dt)[0]

    def f(self, x, u, dt):
        return np.asarray(x, dtype=float) @ self._matrices(dt)[0].T

    def jacobian(self, x, u, dt):
        return self._matrices(dt)[0] if self.params.analytic_jacobian else None

    def Q(self, x, u, dt):
        return self._matrices(dt)[1]


class PositionMeasurement(MeasurementModel):
    """Direct position measurement ``z = p`` (m) of a state whose first ``dim`` elements are p."""

    name = "test_position"

    class Params(Params):
        dim: int = Field(2, ge=1, le=3)
        n: int = Field(4, ge=1, description="state dimension")

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        self.dim = self.params.dim
        self.H = np.eye(self.dim, self.params.n)

    def h(self, x):
        return np.asarray(x, dtype=float)[..., : self.dim].copy()

    def jacobian(self, x):
        return self.H


class RangeMeasurement(MeasurementModel):
    """Ranges (m) from the position ``p = x[:d]`` to each of the beacons (k, d) (paper 001 eq. 6)::

        z_j = |p - b_j|,   dz_j/dp = (p - b_j)^T / |p - b_j|

    ``beacons`` may also come from ``context.beacons``. ``analytic_jacobian: false`` -> None."""

    name = "test_range"

    class Params(Params):
        beacons: list[list[float]] | None = None
        n: int = Field(4, ge=1, description="state dimension")
        analytic_jacobian: bool = True

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        b = self.params.beacons
        if b is None:
            b = [list(v) for v in self.context.beacons.values()]
        self.beacons = np.asarray(b, dtype=float)
        self.dim = self.beacons.shape[0]
        self.d = self.beacons.shape[1]

    def h(self, x):
        diff = np.asarray(x)[..., None, : self.d] - self.beacons
        return np.sqrt((diff * diff).sum(axis=-1))

    def jacobian(self, x):
        if not self.params.analytic_jacobian:
            return None
        diff = np.asarray(x)[: self.d] - self.beacons
        H = np.zeros((self.dim, self.params.n))
        H[:, : self.d] = diff / np.sqrt((diff * diff).sum(axis=-1))[:, None]
        return H


class RejectAll(Gate):
    """A gate that rejects every measurement (for interface checks)."""

    name = "test_reject_all"

    def accept(self, nis: float, dim: int) -> bool:
        return False


# --------------------------------------------------------------------------- reference filter
def reference_kf(x: np.ndarray, P: np.ndarray, steps: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                      np.ndarray, np.ndarray]]):
    """Textbook linear Kalman filter, independent of the plugins: for each ``(F, Q, H, R, z)`` predict
    then update (Joseph form); yields ``(x, P)`` after each update."""
    x = np.array(x, dtype=float)
    P = np.array(P, dtype=float)
    for F, Q, H, R, z in steps:
        x = F @ x
        P = F @ P @ F.T + Q
        S = H @ P @ H.T + R
        K = np.linalg.solve(S, H @ P).T
        x = x + K @ (z - H @ x)
        A = np.eye(len(x)) - K @ H
        P = A @ P @ A.T + K @ R @ K.T
        P = (P + P.T) / 2
        yield x, P


def nees(x_true: np.ndarray, belief: Belief) -> float:
    """Normalised estimation error squared ``e^T P^-1 e``, e = x_true - x (chi-square, n dof)."""
    e = np.asarray(x_true, dtype=float) - belief.x
    return float(e @ np.linalg.solve(belief.cov, e))


# --------------------------------------------------------------------------- registry helpers
def registered(kind: str) -> list[str]:
    """Names of every registered component of ``kind`` (built-ins and installed plugins)."""
    from fusion.registry import default_registry

    return default_registry().names(kind)


def build(kind: str, name: str, params: dict[str, Any] | None = None,
          context: BuildContext | None = None) -> Component:
    """Build a registered component from a params dict (validated by its Params model)."""
    from fusion.registry import default_registry

    cls = default_registry().get(kind, name)
    return cls(cls.Params(**(params or {})), context)


def parametrize_registered(kind: str, argname: str = "name"):
    """``pytest.mark.parametrize(argname, registered(kind))`` (imports pytest)."""
    import pytest

    return pytest.mark.parametrize(argname, registered(kind))


def random_states(layout: StateLayout, k: int, seed: int = 0, scale: float = 1.0) -> np.ndarray:
    """k random states (k, n) for a layout: normal entries, unit quaternion blocks."""
    rng = np.random.default_rng(seed)
    X = scale * rng.standard_normal((k, layout.n))
    for b in layout.blocks:
        if b.kind == "quaternion":
            sl = layout[b.name]
            X[:, sl] /= np.linalg.norm(X[:, sl], axis=1, keepdims=True)
    return X


def _worst(a: np.ndarray, b: np.ndarray) -> float:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b)), initial=0.0))


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


# --------------------------------------------------------------------------- model contracts
def check_process_vectorised(process: ProcessModel, X: np.ndarray, u: np.ndarray | None, dt: float,
                             tol: float = 1e-12) -> float:
    """``f`` on a (k, n) batch equals f row by row (and a (2, k, n) batch keeps its shape)."""
    X = np.asarray(X, dtype=float)
    batch = process.f(X, u, dt)
    rows = np.stack([process.f(x, u, dt) for x in X])
    assert batch.shape == X.shape, f"{process!r}: f on {X.shape} returned {batch.shape}"
    worst = _worst(batch, rows)
    assert worst <= tol, f"{process!r}: f on a batch differs from f row by row by {worst:.3g}"
    deep = process.f(np.stack([X, X]), u, dt)
    assert deep.shape == (2,) + X.shape, f"{process!r}: f on {(2,) + X.shape} returned {deep.shape}"
    Q = process.Q(X[0], u, dt)
    n = X.shape[1]
    assert Q.shape == (n, n), f"{process!r}: Q has shape {Q.shape}, expected {(n, n)}"
    assert _worst(Q, Q.T) <= 1e-12, f"{process!r}: Q not symmetric"
    assert np.linalg.eigvalsh((Q + Q.T) / 2).min() >= -1e-12 * max(1.0, np.abs(Q).max()), \
        f"{process!r}: Q not positive semi-definite"
    return worst


def _central_jacobian(fun, x, eps=1e-6):
    x = np.asarray(x, dtype=float)
    cols = []
    for i in range(x.size):
        h = eps * max(1.0, abs(x[i]))
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        cols.append((np.asarray(fun(xp)) - np.asarray(fun(xm))) / (2 * h))
    return np.stack(cols, axis=-1)


def check_process_jacobian(process: ProcessModel, x: np.ndarray, u: np.ndarray | None, dt: float,
                           tol: float = 1e-6) -> float | None:
    """The analytic ``jacobian`` (if any) matches central finite differences of f (relative tol)."""
    J = process.jacobian(np.asarray(x, dtype=float), u, dt)
    if J is None:
        return None
    Jn = _central_jacobian(lambda v: process.f(v, u, dt), x)
    worst = _worst(J, Jn)
    assert worst <= tol, f"{process!r}: analytic jacobian differs from finite differences by {worst:.3g}"
    return worst


def check_measurement_vectorised(model: MeasurementModel, X: np.ndarray, tol: float = 1e-12) -> float:
    """``h`` on a (k, n) batch equals h row by row, returns (k, dim); residual broadcasts."""
    X = np.asarray(X, dtype=float)
    batch = model.h(X)
    rows = np.stack([model.h(x) for x in X])
    assert batch.shape == (X.shape[0], model.dim), \
        f"{model!r}: h on {X.shape} returned {batch.shape}, expected {(X.shape[0], model.dim)}"
    worst = _worst(batch, rows)
    assert worst <= tol, f"{model!r}: h on a batch differs from h row by row by {worst:.3g}"
    r = model.residual(batch, batch[0])
    assert r.shape == batch.shape, f"{model!r}: residual does not broadcast ({r.shape})"
    return worst


def check_measurement_jacobian(model: MeasurementModel, x: np.ndarray, tol: float = 1e-6) -> float | None:
    """The analytic ``jacobian`` (if any) matches central finite differences of h (relative tol)."""
    J = model.jacobian(np.asarray(x, dtype=float))
    if J is None:
        return None
    Jn = _central_jacobian(model.h, x)
    worst = _worst(J, Jn)
    assert worst <= tol, f"{model!r}: analytic jacobian differs from finite differences by {worst:.3g}"
    return worst
