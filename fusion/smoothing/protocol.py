"""The smoothing capability of a filter (a ``typing.Protocol``, detected once when a smoothed run starts).

The built-in filters get their backends from ``fusion_plugins.filters.rts.backend_for``; a third-party
filter declares the capability by having ``rts_backend()``, returning an :class:`RtsBackendLike`.
"""
from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

from fusion.api import Belief

__all__ = ["SmoothableFilter", "RtsBackendLike"]


class RtsBackendLike(Protocol):
    """What the recorder needs of a backend (``fusion_plugins.filters.rts.RtsBackend`` is one).

    ``sqrt``: beliefs carry ``S`` and the backward pass is in square-root form. ``predict`` and
    ``predict_inputs`` run the filter's own prediction and return ``(b1, step)`` with ``step.G`` the
    smoother gain (n, n), ``step.A`` the filtered covariance (or conditional factor) and ``step.b1`` the
    predicted belief, or None when the belief did not move; ``broken(b)`` the step of a break in the chain;
    ``final(b)`` the covariance (or factor) of the last node. Constructed as ``type(backend)(filter)`` for
    the scheduler's copy of the filter."""

    sqrt: bool

    def predict(self, b0: Belief, process: Any, u: np.ndarray | None, dt: float) -> tuple[Belief, Any]: ...

    def predict_inputs(self, b0: Belief, process: Any, us: np.ndarray, dts: np.ndarray) -> tuple[Belief, Any]: ...

    def broken(self, b: Belief) -> Any: ...

    def final(self, b: Belief) -> np.ndarray: ...


@runtime_checkable
class SmoothableFilter(Protocol):
    """A filter that brings its own Rauch-Tung-Striebel backend."""

    def rts_backend(self) -> RtsBackendLike: ...
