"""The boundary between a filter and the models it calls: what a model is given, and what it gives back.

A model is given read-only views of the filter's own arrays (the belief's mean, an iterate), so a model that
writes into its argument (``x -= bias`` after computing a right result) raises ``ValueError: assignment
destination is read-only`` in the model, where the run names it, instead of rewriting the belief
(tester6 #1). A view costs ~0.4 us and copies nothing.

Every value a model returns is checked once, where the filter receives it: its shape (``f`` (n,) at the
mean, (k, n) on k sigma points; ``jacobian`` (n, n); ``Q`` (n, n); ``h`` (m,) or (k, m); a measurement
``jacobian`` (m, n)), a float64 array (anything numpy reads as one is converted: a list, float32), finite
where the state it was given is finite, and Q with non-negative variances on its diagonal on every call
and symmetric positive semi-definite on its first (:class:`QCheck`). A bad value raises
:class:`fusion.errors.ModelFault` with what was wrong; the run charges it to the model as if the model had
raised (a measurement's message lost and counted malformed, a process model's prediction held, the run
stopped after several in a row). The shape and type tests are attribute compares (~0.1 us); a finiteness
test is one dot product (~0.5 us).

A model of fusion itself (:func:`trusted`) skips the view and the checks: its own tests check its shapes
(tests/models, fusion.testing.check_*) and tests/filters/test_model_boundary.py replays shipped configs with
every check on to the same bytes; the ~3-5 us a step they cost would be 2-5% of a shipped replay. This is
the rule fusion.pipeline applies to sinks (its own are trusted not to write into what they are given).
"""
from __future__ import annotations

import numpy as np

from fusion.errors import ModelFault

__all__ = ["ModelFault", "frozen", "array_of", "finite", "all_finite", "QCheck", "SYMMETRY_RTOL", "PSD_RTOL",
           "MEAN", "ITERATE", "SIGMA", "nonfinite", "trusted"]

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
    subclass a plugin defines), for which the filters skip the read-only view and the checks."""
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
