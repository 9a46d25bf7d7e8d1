"""Scaled unscented transform: weights and sigma points (van der Merwe), shared by ukf and srukf.

Paper 000 Algorithm 1 notes / paper 001 eqs. 11-13, with L the (possibly augmented) dimension::

    lambda = alpha^2 (L + kappa) - L                                   (001 eq. 13)
    eta = sqrt(L + lambda)
    chi_0 = x,  chi_i = x + eta S_i,  chi_{L+i} = x - eta S_i           (000 eq. 3, 001 eq. 11)
    W_m^0 = lambda / (L + lambda),  W_c^0 = W_m^0 + (1 - alpha^2 + beta)
    W_m^i = W_c^i = 1 / (2 (L + lambda)),  i = 1..2L                   (001 eq. 12, as corrected)

``S_i`` is column i of the lower Cholesky factor S (P = S S^T), the same points as FilterPy's
MerweScaledSigmaPoints (which uses the rows of the upper factor). The point order is
``[x, x + eta S_1..L, x - eta S_1..L]``.
"""
from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field

from fusion.api import Params

__all__ = ["SigmaPoints", "UnscentedParams"]

#: Sigma points at most this many standard deviations from the mean (sqrt(alpha^2 (n + kappa))).
MAX_SPREAD = 1e3
#: Largest |W_m^0|, |W_c^0|: the weights sum to 1, so a weighted sum of points loses log10(|W|) of its 16
#: digits to cancellation; 1e10 keeps 6 (alpha = 1e-3 gives ~1e6, DESIGN.md "Performance notes").
MAX_WEIGHT = 1e10


class UnscentedParams(Params):
    """Scaled unscented transform parameters (paper 000 Algorithm 1 notes, paper 001 eqs. 12-13), the
    prediction mode and input batching, shared by ukf and srukf."""

    alpha: float = Field(0.5, gt=0.0, le=1.0, description="spread of the sigma points (0 < alpha <= 1)")
    beta: float = Field(2.0, description="prior-distribution weight on the zeroth point (2: Gaussian)")
    kappa: float = Field(0.0, description="tertiary scaling, usually 0 (n + kappa must be > 0)")
    linear_prediction: Literal["auto", "always", "never"] = Field(
        "auto", description="predict as the linear KF (paper 001 eqs. 9-10): auto = when the process "
                            "model is linear; always = with its (numerical) Jacobian; never = sigma points")
    batch_inputs: bool = Field(
        True, description="integrate a run of input samples (IMU) between measurements with one draw of "
                          "sigma points and the noise of the whole interval (predict_inputs; a process "
                          "model without Q_inputs is predicted sample by sample all the same); false: one "
                          "sigma-point prediction per sample")


class SigmaPoints:
    """Weights and the deviation pattern of the scaled unscented transform in dimension ``n``.

    Attributes: ``Wm``, ``Wc`` (2n+1,); ``w`` the common weight of points 1..2n; ``eta``; ``E``
    (2n+1, n) with ``E @ S.T`` = the sigma points' deviations from the mean; ``gamma = beta - alpha^2``,
    the weight of the mean-to-zeroth-point term when covariances are formed about the zeroth point
    (see plugins/filters/srukf.py, ``zeroth_point: recentred``).
    """

    def __init__(self, n: int, alpha: float, beta: float, kappa: float):
        lam = alpha * alpha * (n + kappa) - n
        c = n + lam
        if not c > 0.0:
            raise ValueError(f"unscented transform needs alpha^2 (n + kappa) > 0; got alpha={alpha}, "
                             f"kappa={kappa}, n={n}: choose kappa > {-n}")
        if c > MAX_SPREAD ** 2:
            raise ValueError(f"sigma points at sqrt(alpha^2 (n + kappa)) = {math.sqrt(c):.3g} standard deviations "
                             f"(alpha={alpha}, kappa={kappa}, n={n}); at most {MAX_SPREAD:g}: beyond, they sample "
                             "the models where the Gaussian has no mass")
        w0 = max(abs(lam / c), abs(lam / c + 1.0 - alpha * alpha + beta))
        if not w0 <= MAX_WEIGHT:
            raise ValueError(f"zeroth sigma-point weight {w0:.3g} (alpha={alpha}, beta={beta}, kappa={kappa}, n={n}) "
                             f"beyond {MAX_WEIGHT:g}: a weighted mean would keep no 6 digits (raise alpha, or bring "
                             "beta near 2)")
        self.n, self.alpha, self.beta, self.kappa, self.lam = n, alpha, beta, kappa, lam
        self.eta = math.sqrt(c)
        self.w = 1.0 / (2.0 * c)
        self.Wm = np.full(2 * n + 1, self.w)
        self.Wm[0] = lam / c
        self.Wc = self.Wm.copy()
        self.Wc[0] += 1.0 - alpha * alpha + beta
        self.Wc_col = self.Wc[:, None]
        self.W1 = self.Wm[1:].copy()             # the weights of points 1..2n
        self.gamma = beta - alpha * alpha
        self.sqrt_w = math.sqrt(self.w)
        # rows [W^i; W^i sqrt(gamma) / sqrt(w)] (i >= 1): one product with the recentred deviations gives
        # their mean and the zeroth-point row of the srukf's joint QR (scaled by 1 / sqrt(w)); one row
        # when gamma <= 0 (no such QR row)
        self.W1_rows = (np.vstack([self.W1, self.W1 * (math.sqrt(self.gamma) / self.sqrt_w)])
                        if self.gamma > 0.0 else self.W1[None, :])
        eye = np.eye(n)
        self.E = self.eta * np.vstack([np.zeros((1, n)), eye, -eye])

    def deviations(self, S: np.ndarray) -> np.ndarray:
        """Deviations (2n+1, n) of the sigma points from the mean for the square root S (n, n)."""
        return self.E @ S.T

    def points(self, x: np.ndarray, S: np.ndarray) -> np.ndarray:
        """Sigma points (2n+1, n) of mean x (n,) and square root S (n, n)."""
        return x + self.E @ S.T

    def __repr__(self) -> str:
        return (f"SigmaPoints(n={self.n}, alpha={self.alpha}, beta={self.beta}, kappa={self.kappa}, "
                f"Wm0={self.Wm[0]:.6g}, Wc0={self.Wc[0]:.6g}, w={self.w:.6g})")
