"""The boundary between a filter and a third party's models: what a model is given, and what it gives back.

A plugin's model is wrapped ONCE, at wiring (:func:`checked`, called by fusion.config.wire): a shallow copy
whose class is a checking subclass of the model's own (so its capabilities, provider and per-run copies are
the model's), and whose calls give the model read-only views of their arguments, so a model that writes into
its argument (``x -= bias`` after computing a right result) raises ``ValueError: assignment destination is
read-only`` in the model, where the run names it, instead of rewriting the belief. A view copies nothing.
The filters themselves have one code path and never check a model.

Every value a checked model returns is checked where it leaves the model: its shape (``f`` (n,) at the
mean, (k, n) on k sigma points; ``jacobian`` (n, n); ``Q`` (n, n); ``h`` (m,) or (k, m); a measurement
``jacobian`` (m, n)), a float64 array (anything numpy reads as one is converted: a list, float32), finite
where the state it was given is finite, and Q with non-negative variances on its diagonal on every call
and symmetric positive semi-definite on its first (:class:`QCheck`). A bad value raises
:class:`fusion.errors.ModelFault` with what was wrong; the run charges it to the model as if the model had
raised (a measurement's message lost and counted malformed, a process model's prediction held, the run
stopped after several in a row).

fusion's own models (:func:`trusted`) are not wrapped: their own tests check their shapes (tests/models,
fusion.testing.check_*) and tests/filters/test_model_boundary.py replays shipped configs with them wrapped
to the same bytes.
"""
from __future__ import annotations

import copy
import dataclasses

import numpy as np

from fusion.errors import ModelFault

__all__ = ["ModelFault", "frozen", "array_of", "finite", "all_finite", "QCheck", "SYMMETRY_RTOL", "PSD_RTOL",
           "MEAN", "ITERATE", "SIGMA", "nonfinite", "trusted", "checked", "unchecked"]

#: What a model was given, for the messages.
MEAN, ITERATE, SIGMA = "the belief's mean", "an iterate of the update", "the sigma points"

_ndarray = np.ndarray
_vdot = np.vdot
_float64 = np.dtype(float)

#: Q's asymmetry allowed on its first use, relative to its largest entry.
SYMMETRY_RTOL = 1e-9
#: Q's most negative eigenvalue allowed on its first use, relative to its largest (rounding of a singular Q).
PSD_RTOL = 1e-9


_TRUSTED: dict[type, bool] = {}


def trusted(model) -> bool:
    """Whether ``model`` is one of fusion's own (its class defined in ``fusion`` or ``fusion_plugins``, not a
    subclass a plugin defines): :func:`checked` leaves it as it is."""
    cls = type(model)
    t = _TRUSTED.get(cls)
    if t is None:
        mod = getattr(cls, "__module__", None) or ""
        t = _TRUSTED[cls] = mod == "fusion" or mod.startswith(("fusion.", "fusion_plugins."))
    return t


def frozen(x: np.ndarray) -> np.ndarray:
    """A read-only view of ``x`` (no copy): what a model is given of the filter's own arrays."""
    v = x.view()
    v.setflags(write=False)      # ~0.2 us less than through v.flags
    return v


def array_of(out, shape: tuple, what: str, given: str) -> np.ndarray:
    """``out``, a model's return value, as a float64 array of ``shape``; else ModelFault.

    :param what: the call, e.g. ``"f"``, ``"h"``, ``"jacobian"``, ``"Q"``.
    :param given: what it was given, for the message (``"the belief's mean (3 states)"``)."""
    if type(out) is not _ndarray or out.dtype != _float64:
        try:
            out = np.asarray(out, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ModelFault(f"{what} returned {type(out).__name__}, not an array of shape {shape} "
                             f"(at {given}: {exc})") from None
    if out.shape != shape:
        got = out.shape
        if given == SIGMA and got:   # said per state, as for one state: the same words from every filter
            raise ModelFault(f"{what} returned shape {got[1:]} a state ({got} on the {shape[0]} sigma points), "
                             f"expected {shape[1:]}")
        raise ModelFault(f"{what} returned shape {got} at {given}, expected {shape}")
    return out


def all_finite(*arrays: np.ndarray | None) -> bool:
    """Every array finite (None skipped)."""
    return all(a is None or bool(np.isfinite(a).all()) for a in arrays)


def finite(out: np.ndarray, what: str, given: str, *inputs: np.ndarray | None) -> None:
    """ModelFault when ``out`` holds NaN or inf while every one of ``inputs`` (what the model was given)
    is finite: at a finite state a model that returns NaN is at fault; at a NaN state it is not.
    The test on the way through is one dot product (~0.5 us, a third of a sum's; its overflow, beyond
    1e154, only sends the value to the exact test)."""
    s = _vdot(out, out)
    if s - s != 0.0:
        nonfinite(out, what, given, *inputs)


def nonfinite(out: np.ndarray, what: str, given: str, *inputs: np.ndarray | None) -> None:
    """The exact test behind :func:`finite` (and the callers' combined dot products)."""
    if not bool(np.isfinite(out).all()) and all_finite(*inputs):
        raise ModelFault(f"{what} returned NaN or inf at {given}, which is finite")


class QCheck:
    """The test of a process noise Q (n, n): on every call its shape and finiteness (one dot product); on the
    first call of each source (``"Q"``, ``"Q_inputs"``) also a non-negative diagonal (a sign slip), symmetry
    and positive semi-definiteness within :data:`SYMMETRY_RTOL` / :data:`PSD_RTOL` (an eigen-decomposition,
    ~10 us, once: every call would cost a singular Q, the INS's, ~5% of a prediction). One per filter: the
    memory of which sources it has fully checked."""

    def __init__(self) -> None:
        self._full: set = set()

    def __call__(self, Q, n: int, what: str = "Q", given: str = "the belief's mean", *inputs) -> np.ndarray:
        Q = array_of(Q, (n, n), what, given)
        s = _vdot(Q, Q)
        if s - s != 0.0:
            nonfinite(Q, what, given, *inputs)
        if what not in self._full:
            self.full(Q, what)
        return Q

    def full(self, Q: np.ndarray, what: str) -> None:
        """The first use's test of a finite Q: diagonal, symmetry, eigenvalues."""
        if all_finite(Q):
            d = Q.diagonal()
            lo = float(d.min())
            if lo < 0.0:
                raise ModelFault(f"{what} has a negative variance on its diagonal ({lo:.6g} at index "
                                 f"{int(np.argmin(d))}): a process noise covariance must be positive "
                                 "semi-definite")
            big = float(np.abs(Q).max())
            asym = float(np.abs(Q - Q.T).max())
            if asym > SYMMETRY_RTOL * big:
                raise ModelFault(f"{what} is not symmetric (|Q - Q^T| up to {asym:.3g}, largest entry {big:.3g})")
            w = np.linalg.eigvalsh(Q)
            if w[0] < -PSD_RTOL * max(float(w[-1]), 0.0):
                raise ModelFault(f"{what} is not positive semi-definite (eigenvalue {w[0]:.6g}, largest "
                                 f"{w[-1]:.6g})")
            self._full.add(what)

    def stack(self, Q, k: int, n: int, what: str, given: str, *inputs) -> np.ndarray:
        """A stack of k process noises (k, n, n) (``LinearisesInputRuns``: one a sample): the shape and
        finiteness of all, and the first one fully on the first call."""
        Q = array_of(Q, (k, n, n), what, given)
        s = _vdot(Q, Q)
        if s - s != 0.0:
            nonfinite(Q, what, given, *inputs)
        if k and what not in self._full:
            self.full(Q[0], what)
        return Q


# ------------------------------------------------------------------------------------------ the adapter
def _given(x: np.ndarray) -> str:
    return MEAN if np.ndim(x) == 1 else SIGMA


def _out(out, shape: tuple, what: str, x: np.ndarray, *inputs) -> np.ndarray:
    """``out`` of ``what`` at ``x``: a float64 array of ``shape``, finite where its inputs are."""
    given = _given(x)
    out = array_of(out, shape, what, given)
    finite(out, what, given, x, *inputs)
    return out


def _q(self, Q, x: np.ndarray, what: str, *inputs) -> np.ndarray:
    n = x.shape[-1]
    return self._fusion_qcheck(Q, n, what, _given(x), x, *inputs)


def _f(self, x, u, dt):
    x = frozen(np.asarray(x, dtype=float))
    return _out(super(self._fusion_checked, self).f(x, u, dt), x.shape, "f", x)


def _process_jacobian(self, x, u, dt):
    x = frozen(np.asarray(x, dtype=float))
    F = super(self._fusion_checked, self).jacobian(x, u, dt)
    if F is None:
        return None
    n = x.shape[-1]
    return _out(F, (n, n), "jacobian", x)


def _Q(self, x, u, dt):
    x = frozen(np.asarray(x, dtype=float))
    return _q(self, super(self._fusion_checked, self).Q(x, u, dt), x, "Q")


def _f_inputs(self, X, us, dts):
    X = frozen(np.asarray(X, dtype=float))
    return _out(super(self._fusion_checked, self).f_inputs(X, us, dts), X.shape, "f_inputs", X, us)


def _Q_inputs(self, x0, x1, us, dts):
    x0, x1 = frozen(np.asarray(x0, dtype=float)), frozen(np.asarray(x1, dtype=float))
    return _q(self, super(self._fusion_checked, self).Q_inputs(x0, x1, us, dts), x0, "Q_inputs", x1)


def _linearise_inputs(self, x, us, dts):
    x = frozen(np.asarray(x, dtype=float))
    run = super(self._fusion_checked, self).linearise_inputs(x, us, dts)
    if run is None:
        return None
    x1, F, Q = run
    n, k = x.shape[0], len(dts)
    x1 = array_of(x1, (n,), "linearise_inputs' mean", MEAN)
    finite(x1, "linearise_inputs' mean", MEAN, x, us)
    F = array_of(F, (k, n, n), "linearise_inputs' jacobians", MEAN)
    finite(F, "linearise_inputs' jacobians", MEAN, x, us)
    Q = self._fusion_qcheck.stack(Q, k, n, "linearise_inputs' Q", MEAN, x, us)
    return x1, F, Q


def _f_with_noise(self, X, W, u, dt):
    X, W = frozen(np.asarray(X, dtype=float)), frozen(np.asarray(W, dtype=float))
    return _out(super(self._fusion_checked, self).f_with_noise(X, W, u, dt), X.shape, "f_with_noise", X, W)


def _m_shape(self, x: np.ndarray, out) -> tuple:
    """h's shape at x: (m,) a state, m the model's ``dim`` (else what h gave)."""
    m = self.dim or (np.shape(out)[-1] if np.ndim(out) else 1)
    return x.shape[:-1] + (int(m),)


def _h(self, x):
    x = frozen(np.asarray(x, dtype=float))
    z = super(self._fusion_checked, self).h(x)
    return _out(z, _m_shape(self, x, z), "h", x)


def _measurement_jacobian(self, x):
    x = frozen(np.asarray(x, dtype=float))
    H = super(self._fusion_checked, self).jacobian(x)
    if H is None:
        return None
    if type(H) is not np.ndarray or H.ndim != 2:      # a row for a scalar measurement is read as (1, n)
        H = np.atleast_2d(array_of(H, np.shape(H), "jacobian", MEAN))
    return _out(H, (self.dim or H.shape[0], x.shape[-1]), "jacobian", x)


def _h_with_noise(self, X, V):
    X, V = frozen(np.asarray(X, dtype=float)), frozen(np.asarray(V, dtype=float))
    Z = super(self._fusion_checked, self).h_with_noise(X, V)
    return _out(Z, _m_shape(self, X, Z), "h_with_noise", X, V)


def _observe(self, message):
    """The model's observation, its model checked too (a model bound to the message may be a new object)."""
    o = super(self._fusion_checked, self).observe(message)
    model = getattr(o, "model", None)
    if (model is None or model is self or getattr(type(model), "_fusion_checked", None) is type(model)
            or not dataclasses.is_dataclass(o)):
        return o
    return dataclasses.replace(o, model=checked(model))


_PROCESS = {"f": _f, "jacobian": _process_jacobian, "Q": _Q, "f_inputs": _f_inputs, "Q_inputs": _Q_inputs,
            "linearise_inputs": _linearise_inputs, "f_with_noise": _f_with_noise}
_MEASUREMENT = {"h": _h, "jacobian": _measurement_jacobian, "h_with_noise": _h_with_noise, "observe": _observe}
_CLASSES: dict[type, type] = {}


def _checking_class(cls: type) -> type:
    """The checking subclass of ``cls`` (memoised): the calls of :data:`_PROCESS` or :data:`_MEASUREMENT` that
    ``cls`` has, no others (so it has the same capabilities), under the same name and module (the same
    provider in messages)."""
    sub = _CLASSES.get(cls)
    if sub is None:
        from fusion.api import ProcessModel

        calls = _PROCESS if issubclass(cls, ProcessModel) else _MEASUREMENT
        body = {name: fn for name, fn in calls.items() if callable(getattr(cls, name, None))}
        body.update(__module__=cls.__module__, __qualname__=cls.__qualname__, __doc__=cls.__doc__,
                    __reduce_ex__=_reduce_checked)
        sub = _CLASSES[cls] = type(cls.__name__, (cls,), body)
        sub._fusion_checked = sub
    return sub


def unchecked(model):
    """The model a :func:`checked` one wraps (a shallow copy of it, of its own class); any other as it is."""
    cls = type(model)
    if getattr(cls, "_fusion_checked", None) is not cls:
        return model
    base = cls.__mro__[1]
    raw = base.__new__(base)
    raw.__dict__.update((k, v) for k, v in model.__dict__.items() if k != "_fusion_qcheck")
    return raw


def _reduce_checked(self, protocol):
    """Pickled (and deep-copied) as ``checked(the model)``: the checking class is made at run time, so it is
    not found by name; the copy gets a fresh QCheck."""
    return checked, (unchecked(self),)


def checked(model):
    """``model`` with every call checked (the module's docstring), or ``model`` itself when it is one of
    fusion's own (:func:`trusted`) or already checked. The model is not changed: the checked one is a
    shallow copy of it (with its own :class:`QCheck`)."""
    if model is None or trusted(model) or getattr(type(model), "_fusion_checked", None) is type(model):
        return model
    wrapped = copy.copy(model)
    wrapped.__class__ = _checking_class(type(model))
    wrapped._fusion_qcheck = QCheck()
    return wrapped
