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
test is one reduction (~1 us).
"""
from __future__ import annotations

import numpy as np

from fusion.errors import ModelFault

__all__ = ["ModelFault", "frozen", "array_of", "finite", "all_finite", "QCheck", "SYMMETRY_RTOL", "PSD_RTOL",
           "MEAN", "ITERATE", "SIGMA"]

#: What a model was given, for the messages.
MEAN, ITERATE, SIGMA = "the belief's mean", "an iterate of the update", "the sigma points"

_ndarray = np.ndarray
_float64 = np.dtype(float)

#: Q's asymmetry allowed on its first use, relative to its largest entry.
SYMMETRY_RTOL = 1e-9
#: Q's most negative eigenvalue allowed on its first use, relative to its largest (rounding of a singular Q).
PSD_RTOL = 1e-9


def frozen(x: np.ndarray) -> np.ndarray:
    """A read-only view of ``x`` (no copy): what a model is given of the filter's own arrays."""
    v = x.view()
    v.flags.writeable = False
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
    One sum on the way through (~1 us)."""
    s = float(out.sum())
    if s - s != 0.0 and not bool(np.isfinite(out).all()) and all_finite(*inputs):
        raise ModelFault(f"{what} returned NaN or inf at {given}, which is finite")


class QCheck:
    """The test of a process noise Q (n, n): on every call its shape, a finite sum and a non-negative
    diagonal (a sign slip, NaN); on the first call of each source (``"Q"``, ``"Q_inputs"``) also symmetry and
    positive semi-definiteness within :data:`SYMMETRY_RTOL` / :data:`PSD_RTOL` (an eigen-decomposition,
    ~10 us, once). One per filter: the memory of which sources it has fully checked."""

    def __init__(self) -> None:
        self._full: set = set()

    def __call__(self, Q, n: int, what: str = "Q", given: str = "the belief's mean", *inputs) -> np.ndarray:
        Q = array_of(Q, (n, n), what, given)
        d = Q.diagonal()
        lo = float(d.min())
        s = float(Q.sum())
        if not lo >= 0.0 or s - s != 0.0:
            if not all_finite(Q):
                if all_finite(*inputs):
                    raise ModelFault(f"{what} returned NaN or inf at {given}, which is finite")
                return Q
            raise ModelFault(f"{what} has a negative variance on its diagonal ({lo:.6g} at index "
                             f"{int(np.argmin(d))}): a process noise covariance must be positive semi-definite")
        if what not in self._full:
            big = float(np.abs(Q).max())
            asym = float(np.abs(Q - Q.T).max())
            if asym > SYMMETRY_RTOL * big:
                raise ModelFault(f"{what} is not symmetric (|Q - Q^T| up to {asym:.3g}, largest entry {big:.3g})")
            w = np.linalg.eigvalsh(Q)
            if w[0] < -PSD_RTOL * max(float(w[-1]), 0.0):
                raise ModelFault(f"{what} is not positive semi-definite (eigenvalue {w[0]:.6g}, largest "
                                 f"{w[-1]:.6g})")
            self._full.add(what)
        return Q

    def stack(self, Q, k: int, n: int, what: str, given: str, *inputs) -> np.ndarray:
        """A stack of k process noises (k, n, n) (``LinearisesInputRuns``: one a sample): the shape, a finite
        sum and non-negative diagonals of all, and the first one fully on the first call."""
        Q = array_of(Q, (k, n, n), what, given)
        lo = float(np.diagonal(Q, 0, 1, 2).min()) if k else 0.0
        s = float(Q.sum())
        if k and (not lo >= 0.0 or s - s != 0.0 or what not in self._full):
            for Qj in Q:
                self(Qj, n, what, given, *inputs)
        return Q
