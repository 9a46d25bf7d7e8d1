"""chi2: validation gate on the normalised innovation squared (NIS)."""
from __future__ import annotations

from pydantic import Field, model_validator

from fusion.api import Gate, Params


class Chi2Gate(Gate):
    r"""Chi-square validation gate: accept a measurement of dimension m when

        NIS = y^T S^-1 y <= chi2.ppf(probability, m)

    (y the innovation, S its covariance; the NIS of a consistent filter is chi-square with m degrees
    of freedom). ``n_sigma`` instead gates a scalar measurement at |y| <= n_sigma sqrt(S), i.e.
    NIS <= n_sigma^2 (paper 003 rejects echoes at 2-3 sigma); for m > 1 it uses the same probability
    as the 1-D n-sigma interval, ``chi2.ppf(chi2.cdf(n_sigma^2, 1), m)``. Give one of the two
    (default probability 0.997).

    ``checked`` and ``rejected`` count the calls and the rejections (one gate per sensor, so these
    are per-sensor counts); ``last_threshold`` is the threshold of the last call.
    """

    name = "chi2"

    class Params(Params):
        """Gate threshold: a probability, or n_sigma for scalar measurements."""

        probability: float | None = Field(None, gt=0.0, lt=1.0,
                                          description="probability mass inside the gate (e.g. 0.997)")
        n_sigma: float | None = Field(None, gt=0.0, description="gate at n standard deviations (scalars)")

        @model_validator(mode="after")
        def _one_of(self):
            if self.probability is not None and self.n_sigma is not None:
                raise ValueError("give probability or n_sigma, not both")
            if self.probability is None and self.n_sigma is None:
                self.probability = 0.997
            return self

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        self.checked = 0
        self.rejected = 0
        self.last_threshold: float | None = None
        self._thresholds: dict[int, float] = {}

    def threshold(self, dim: int) -> float:
        """The NIS threshold for a measurement of dimension ``dim``."""
        th = self._thresholds.get(dim)
        if th is None:
            if dim < 1:
                raise ValueError(f"gate {self.name!r}: measurement dimension must be >= 1, got {dim}")
            from fusion.chisquare import chi2

            p = self.params
            if p.n_sigma is not None:
                th = float(p.n_sigma) ** 2 if dim == 1 else float(chi2.ppf(chi2.cdf(p.n_sigma ** 2, 1), dim))
            else:
                th = float(chi2.ppf(p.probability, dim))
            self._thresholds[dim] = th
        return th

    def accept(self, nis: float, dim: int) -> bool:
        """True when the measurement passes (NIS <= threshold); a NaN NIS is rejected."""
        th = self.last_threshold = self.threshold(dim)
        self.checked += 1
        ok = bool(nis <= th)
        if not ok:
            self.rejected += 1
        return ok
