"""Batched beliefs and update results."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fusion.api import Belief


@dataclass
class BatchBelief:
    """N Gaussian beliefs at one time ``t`` (s): means ``x`` (N, n) and either covariances ``P``
    (N, n, n) or their lower Cholesky factors ``S`` (N, n, n, square-root filters)."""

    t: float
    x: np.ndarray
    P: np.ndarray | None = None
    S: np.ndarray | None = None

    @property
    def N(self) -> int:
        return self.x.shape[0]

    @property
    def cov(self) -> np.ndarray:
        """Covariances (N, n, n) (S S^T for a square-root belief)."""
        if self.P is not None:
            return self.P
        return self.S @ np.swapaxes(self.S, -1, -2)  # type: ignore[operator]

    @property
    def sd(self) -> np.ndarray:
        """Standard deviations (N, n)."""
        if self.P is None:
            return np.sqrt(np.einsum("kij,kij->ki", self.S, self.S))
        return np.sqrt(np.clip(np.diagonal(self.P, axis1=-2, axis2=-1), 0.0, None))

    def belief(self, i: int) -> Belief:
        """Filter i as a single :class:`fusion.api.Belief`."""
        if self.P is not None:
            return Belief(self.t, self.x[i].copy(), P=self.P[i].copy())
        return Belief(self.t, self.x[i].copy(), S=self.S[i].copy())  # type: ignore[index]

    @classmethod
    def stack(cls, beliefs: Sequence[Belief]) -> "BatchBelief":
        """N single beliefs (the same t and kind) as one batch."""
        t = beliefs[0].t
        x = np.stack([b.x for b in beliefs]).astype(float)
        if beliefs[0].P is not None:
            return cls(t, x, P=np.stack([b.P for b in beliefs]).astype(float))
        return cls(t, x, S=np.stack([b.S for b in beliefs]).astype(float))

    def where(self, mask: np.ndarray, other: "BatchBelief") -> "BatchBelief":
        """This belief where ``mask`` (N,) is True, ``other`` elsewhere (same kind and shapes)."""
        m1, m2 = mask[:, None], mask[:, None, None]
        x = np.where(m1, self.x, other.x)
        if self.P is not None:
            return BatchBelief(self.t, x, P=np.where(m2, self.P, other.P))
        return BatchBelief(self.t, x, S=np.where(m2, self.S, other.S))


@dataclass
class BatchUpdate:
    """A batched update: ``belief`` (rejected filters keep their prior), ``innovation`` (N, m), its
    covariance ``S`` (N, m, m), ``nis`` (N,), ``accepted`` (N,) bool."""

    belief: BatchBelief
    innovation: np.ndarray
    S: np.ndarray
    nis: np.ndarray
    accepted: np.ndarray
