"""Numerical helpers of the contracts: random states on a layout, the worst relative mismatch, and a
Jacobian by Richardson-extrapolated central differences written independently of the filters' own
(plugins/filters/jacobian.py), so a contract compares two different computations."""
from __future__ import annotations

import numpy as np

from fusion.api import StateLayout

__all__ = ["random_states", "worst", "reference_jacobian"]


def random_states(layout: StateLayout, k: int, seed: int = 0, scale: float = 1.0) -> np.ndarray:
    """k random states (k, n) for a layout: normal entries, unit quaternion blocks."""
    rng = np.random.default_rng(seed)
    X = scale * rng.standard_normal((k, layout.n))
    for b in layout.blocks:
        if b.kind == "quaternion":
            sl = layout[b.name]
            X[:, sl] /= np.linalg.norm(X[:, sl], axis=1, keepdims=True)
    return X


def worst(a: np.ndarray, b: np.ndarray) -> float:
    """max |a - b| / max(1, |b|) (relative where values exceed 1)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b)), initial=0.0))


def reference_jacobian(fun, x, difference=None, eps: float = 1e-4) -> np.ndarray:
    """d fun / dx (m, n) at x (n,): central differences at steps h and h/2 per element, one point at a
    time, combined by Richardson extrapolation (error O(h^4)); ``difference(a, b)`` for outputs that
    wrap (angles), plain subtraction otherwise."""
    x = np.asarray(x, dtype=float)
    diff = difference or (lambda a, b: np.asarray(a) - np.asarray(b))
    cols = []
    for i in range(x.size):
        h = eps * max(1.0, abs(x[i]))
        d = []
        for step in (h, h / 2):
            xp, xm = x.copy(), x.copy()
            xp[i] += step
            xm[i] -= step
            d.append(np.asarray(diff(fun(xp), fun(xm)), dtype=float) / (2 * step))
        cols.append((4 * d[1] - d[0]) / 3)
    return np.stack(cols, axis=-1)
