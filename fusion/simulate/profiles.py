"""Smooth scalar profiles shared by the trajectories.

The quintic smoothstep ``H(x) = 10x^3 - 15x^4 + 6x^5`` rises from 0 to 1 on [0, 1] with zero first and
second derivatives at both ends, so a speed or heading that follows it has a continuous acceleration
(and a continuous jerk). ``max H' = 15/8`` at ``x = 1/2``.
"""
from __future__ import annotations

import numpy as np

H_PRIME_MAX = 15.0 / 8.0


def smoothstep(x: np.ndarray) -> np.ndarray:
    """H(x) clipped to [0, 1] outside the unit interval."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (10.0 + x * (-15.0 + 6.0 * x))


def smoothstep_d1(x: np.ndarray) -> np.ndarray:
    """H'(x) = 30 x^2 (1 - x)^2 (zero outside [0, 1])."""
    x = np.clip(x, 0.0, 1.0)
    return 30.0 * x * x * (1.0 - x) ** 2


def smoothstep_d2(x: np.ndarray) -> np.ndarray:
    """H''(x) = 60 x (1 - x)(1 - 2x) (zero outside [0, 1])."""
    x = np.clip(x, 0.0, 1.0)
    return 60.0 * x * (1.0 - x) * (1.0 - 2.0 * x)


def smoothstep_int(x: np.ndarray) -> np.ndarray:
    """G(x) = integral of H from 0 to x = 2.5 x^4 - 3 x^5 + x^6 (G(1) = 1/2), for x in [0, 1]."""
    x = np.clip(x, 0.0, 1.0)
    return x ** 4 * (2.5 + x * (-3.0 + x))
