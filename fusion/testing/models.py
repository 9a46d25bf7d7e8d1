"""The contracts of components, models and filters, for plugin authors and the built-ins alike.

One call per kind takes the component CLASS, its params (a dict, validated by its Params model) and what
it needs to be built (a layout, beacons), builds it exactly as a config would, and checks everything the
run relies on; a build error is raised, never skipped. Each returns a small report (worst mismatches)
and raises AssertionError naming the component and the worst mismatch otherwise.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from fusion.api import (KINDS, BuildContext, Component, MalformedMessage, MeasurementModel, Message, Observation,
                        Params, ProcessModel, StateLayout, near_misses)

from .numeric import random_states, reference_jacobian, worst as _worst

__all__ = [
    "check_component", "check_measurement", "check_process", "check_filter",
    "check_process_vectorised", "check_process_jacobian", "check_measurement_vectorised",
    "check_measurement_jacobian",
]


# --------------------------------------------------------------------------- any component
def check_component(cls: type[Component]) -> None:
    """What every component declares: a registry ``name``, a known ``kind``, a docstring (shown by ``fusion
    plugins --verbose``), a ``Params`` model derived from fusion.api.Params that forbids unknown keys, and
    no method one edit away from a capability (a misspelt ``f_inputs`` would silently switch it off)."""
    who = cls.__qualname__
    assert isinstance(cls, type) and issubclass(cls, Component), f"{who}: not a fusion.api.Component"
    assert cls.name and isinstance(cls.name, str), f"{who}: no registry name (set name = '...')"
    assert cls.kind in KINDS, f"{who}: kind {cls.kind!r} is not one of {KINDS}"
    assert (cls.__doc__ or "").strip() and cls.__doc__ is not Component.__doc__, \
        f"{who}: no docstring (units and frames, shown by fusion plugins --verbose)"
    P = cls.Params
    assert isinstance(P, type) and issubclass(P, Params), f"{who}: Params must derive from fusion.api.Params"
    assert P.model_config.get("extra") == "forbid", f"{who}: Params must forbid unknown keys (extra='forbid')"
    try:
        P(**{"_no_such_parameter_": 1})
    except Exception:
        pass
    else:  # pragma: no cover - extra='forbid' guarantees it
        raise AssertionError(f"{who}: Params accepted an unknown key")
    misses = near_misses(cls)
    assert not misses, "; ".join(misses)


def _build(cls, params, context):
    return cls(cls.Params(**dict(params or {})), context)


# --------------------------------------------------------------------------- measurement models
def check_measurement(cls: type[MeasurementModel], params: Mapping[str, Any] | None = None,
                      layout: StateLayout | None = None, *, beacons: Mapping[str, Any] | None = None,
                      context: BuildContext | None = None, message: Message | None = None,
                      states: np.ndarray | None = None, scale: float = 3.0, tol: float = 1e-6) -> dict:
    """The measurement-model contract on ``cls`` built with ``params`` for a state ``layout``.

    * :func:`check_component`;
    * with ``message`` (a decoded message of the sensor, needed by models that bind to it, e.g. the range
      to the beacon it names): ``observe(message)`` returns an Observation at the message's time whose
      ``z`` has its model's ``dim`` values, carrying an R only if the model declares ``carries_R``; a
      message of non-numbers raises MalformedMessage (never another exception);
    * ``h`` vectorised over leading axes: ``(k, n) -> (k, dim)`` equal to row by row, ``(2, k, n) ->
      (2, k, dim)``; ``residual`` broadcasts;
    * the Jacobian against an independent numerical one (Richardson-extrapolated central differences),
      always: the analytic ``jacobian`` when there is one, else the central differences the EKF falls
      back on (one vectorised call of h on 2n points);
    * ``linear = True`` is true: h affine (the same Jacobian everywhere, h of a mixture the mixture of h).

    ``states`` (k, n): where to check (default 9 random states, unit quaternions, ``scale`` wide)."""
    check_component(cls)
    if context is None:
        beacons = {k: np.asarray(v, dtype=float) for k, v in (beacons or {}).items()}
        context = BuildContext(layout=layout, beacons=beacons, sensor="test")
    layout = layout if layout is not None else context.layout
    assert layout is not None, f"{cls.__qualname__}: check_measurement needs a state layout"
    model = _build(cls, params, context)
    report: dict[str, Any] = {}
    if message is not None:
        obs = model.observe(message)
        assert isinstance(obs, Observation), f"{model!r}: observe returned {obs!r}, expected an Observation"
        assert obs.t == message.t, f"{model!r}: observation at t={obs.t}, message at t={message.t}"
        assert np.shape(obs.z) == (obs.model.dim,), \
            f"{model!r}: observation z has shape {np.shape(obs.z)}, its model's dim is {obs.model.dim}"
        assert obs.R is None or model.carries_R, \
            f"{model!r}: observe attached an R but the model does not declare carries_R = True"
        try:
            model.observe(Message(message.t, message.sensor, ("not a number",) * max(1, len(message.values)),
                                  message.line))
        except MalformedMessage:
            pass
        except Exception as exc:
            raise AssertionError(f"{model!r}: a message of non-numbers raised {type(exc).__name__}: {exc} "
                                 "(raise fusion.api.MalformedMessage)") from None
        model = obs.model
    assert model.dim >= 1, f"{model!r}: dim is {model.dim}"
    X = random_states(layout, 9, seed=5, scale=scale) if states is None else np.asarray(states, dtype=float)
    _check_finite_h(model, layout, X)
    report["vectorised"] = check_measurement_vectorised(model, X)
    report["jacobian"] = check_measurement_jacobian(model, X[0], tol=tol)
    if model.linear:
        H0, H1 = _measurement_jacobian(model, X[0]), _measurement_jacobian(model, X[1])
        assert _worst(H0, H1) <= 1e-8, f"{model!r}: declares linear = True but its Jacobian depends on x"
        mid = model.h(0.3 * X[0] + 0.7 * X[1])
        assert _worst(mid, 0.3 * model.h(X[0]) + 0.7 * model.h(X[1])) <= 1e-9, \
            f"{model!r}: declares linear = True but h is not affine"
    return report


def _check_finite_h(model: MeasurementModel, layout: StateLayout, X: np.ndarray) -> None:
    """h finite at the states X and at rest (zeros, identity quaternions: where most filters start): the
    run refuses an update whose prediction is not finite, so a model NaN there is never used there."""
    rest = np.zeros(layout.n)
    for b in layout.blocks:
        if b.kind == "quaternion":
            rest[layout[b.name].start] = 1.0
    for where, x in [("at rest (zeros, identity quaternions)", rest)] + [(f"at state {i}", x) for i, x in enumerate(X)]:
        with np.errstate(all="ignore"):
            y = np.asarray(model.h(x), dtype=float)
        assert np.all(np.isfinite(y)), f"{model!r}: h is not finite {where}: {y.tolist()} for x = {x.tolist()}"


def _central_batch(fun, x: np.ndarray, difference=None) -> np.ndarray:
    """The central differences the EKF falls back on: one call of ``fun`` on the (2n, n) perturbed states,
    step eps^(1/3) max(|x_i|, 1) (written here again, independently of plugins/filters/jacobian.py)."""
    n = x.shape[0]
    h = np.finfo(float).eps ** (1.0 / 3.0) * np.maximum(np.abs(x), 1.0)
    X = np.tile(x, (2 * n, 1))
    X[np.arange(n), np.arange(n)] += h
    X[n + np.arange(n), np.arange(n)] -= h
    step = X[np.arange(n), np.arange(n)] - X[n + np.arange(n), np.arange(n)]
    Y = np.asarray(fun(X), dtype=float)
    dY = Y[:n] - Y[n:] if difference is None else difference(Y[:n], Y[n:])
    return (dY / step[:, None]).T


def _measurement_jacobian(model: MeasurementModel, x: np.ndarray) -> np.ndarray:
    J = model.jacobian(x)
    return np.atleast_2d(J) if J is not None else _central_batch(model.h, x, model.residual)


def check_measurement_vectorised(model: MeasurementModel, X: np.ndarray, tol: float = 1e-12) -> float:
    """``h`` on a (k, n) batch equals h row by row and returns (k, dim); a (2, k, n) batch keeps its
    leading axes; residual broadcasts."""
    X = np.asarray(X, dtype=float)
    batch = model.h(X)
    rows = np.stack([model.h(x) for x in X])
    assert batch.shape == (X.shape[0], model.dim), \
        f"{model!r}: h on {X.shape} returned {batch.shape}, expected {(X.shape[0], model.dim)}"
    worst = _worst(batch, rows)
    assert worst <= tol, f"{model!r}: h on a batch differs from h row by row by {worst:.3g}"
    deep = model.h(np.stack([X, X]))
    assert deep.shape == (2, X.shape[0], model.dim), \
        f"{model!r}: h on {(2,) + X.shape} returned {deep.shape}, expected {(2, X.shape[0], model.dim)}"
    r = model.residual(batch, batch[0])
    assert r.shape == batch.shape, f"{model!r}: residual does not broadcast ({r.shape})"
    return worst


def check_measurement_jacobian(model: MeasurementModel, x: np.ndarray, tol: float = 1e-6) -> float:
    """The Jacobian a filter uses (the analytic ``jacobian``, else the EKF's central differences) matches
    an independent numerical one (relative ``tol``); returns the worst mismatch."""
    x = np.asarray(x, dtype=float)
    J = _measurement_jacobian(model, x)
    Jn = reference_jacobian(model.h, x, model.residual)
    assert J.shape == Jn.shape, f"{model!r}: Jacobian has shape {J.shape}, expected {Jn.shape}"
    worst = _worst(J, Jn)
    what = "analytic jacobian" if model.jacobian(x) is not None else "numerical Jacobian (no analytic one)"
    assert worst <= tol, f"{model!r}: {what} differs from finite differences by {worst:.3g}"
    return worst


# --------------------------------------------------------------------------- process models
def check_process(cls: type[ProcessModel], params: Mapping[str, Any] | None = None, *,
                  context: BuildContext | None = None, u: np.ndarray | None = None, dt: float = 0.01,
                  states: np.ndarray | None = None, tol: float = 1e-6) -> dict:
    """The process-model contract on ``cls`` built with ``params``: :func:`check_component`; a layout;
    ``f`` vectorised over leading axes and equal to row by row; ``Q`` (n, n) symmetric positive
    semi-definite; the Jacobian (analytic, else the EKF's central differences) against an independent
    numerical one; ``normalize`` puts every unit quaternion block on the unit sphere; ``linear = True``
    is true (F independent of x); ``input_from`` of a message of ``input_dim`` numbers gives u.
    ``u`` defaults to zeros of ``input_dim`` (None without input)."""
    check_component(cls)
    process = _build(cls, params, context if context is not None else BuildContext())
    layout = process.layout
    assert isinstance(layout, StateLayout) and layout.n >= 1, f"{process!r}: no state layout"
    if u is None and process.input_dim:
        u = np.zeros(process.input_dim)
    X = random_states(layout, 9, seed=4) if states is None else np.asarray(states, dtype=float)
    report: dict[str, Any] = {"vectorised": check_process_vectorised(process, X, u, dt)}
    report["jacobian"] = check_process_jacobian(process, X[0], u, dt, tol=tol)
    Xn = process.normalize(1.5 * X)
    for sl in layout.unit_quaternions:
        assert np.allclose(np.linalg.norm(Xn[:, sl], axis=1), 1.0, rtol=0, atol=1e-12), \
            f"{process!r}: normalize left a quaternion block off the unit sphere"
    if process.linear:
        assert _worst(_process_jacobian(process, X[0], u, dt), _process_jacobian(process, X[1], u, dt)) <= 1e-8, \
            f"{process!r}: declares linear = True but its Jacobian depends on x"
    if process.input_dim:
        got = process.input_from(Message(0.0, "imu", tuple(float(v) for v in u)))  # type: ignore[union-attr]
        assert np.shape(got) == (process.input_dim,), f"{process!r}: input_from gave shape {np.shape(got)}"
    return report


def _process_jacobian(process: ProcessModel, x, u, dt) -> np.ndarray:
    F = process.jacobian(x, u, dt)
    return F if F is not None else _central_batch(lambda X: process.f(X, u, dt), x)


def check_process_vectorised(process: ProcessModel, X: np.ndarray, u: np.ndarray | None, dt: float,
                             tol: float = 1e-12) -> float:
    """``f`` on a (k, n) batch equals f row by row (and a (2, k, n) batch keeps its shape); Q is (n, n),
    symmetric and positive semi-definite."""
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


def check_process_jacobian(process: ProcessModel, x: np.ndarray, u: np.ndarray | None, dt: float,
                           tol: float = 1e-6) -> float:
    """The Jacobian a filter uses (analytic, else the EKF's central differences) matches an independent
    numerical one of f (relative ``tol``); returns the worst mismatch."""
    x = np.asarray(x, dtype=float)
    F = _process_jacobian(process, x, u, dt)
    Fn = reference_jacobian(lambda v: process.f(v, u, dt), x)
    worst = _worst(F, Fn)
    what = "analytic jacobian" if process.jacobian(x, u, dt) is not None else "numerical Jacobian (no analytic one)"
    assert worst <= tol, f"{process!r}: {what} differs from finite differences by {worst:.3g}"
    return worst


# --------------------------------------------------------------------------- filters
def check_filter(cls, params: Mapping[str, Any] | None = None, *, context: BuildContext | None = None,
                 tol: float = 1e-9) -> float:
    """The filter contract: :func:`check_component`, equal to the textbook Kalman filter on a linear-
    Gaussian problem (``tol``), and the interface (a rejected update returns the input belief, ...)."""
    from .filters import check_filter_interface, check_filter_linear_exactness

    check_component(cls)
    flt = _build(cls, params, context)
    worst = check_filter_linear_exactness(flt, tol=tol)
    check_filter_interface(flt)
    return worst
