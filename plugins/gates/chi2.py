"""chi2: validation gate on the normalised innovation squared (NIS)."""
from __future__ import annotations

from functools import lru_cache

from pydantic import Field, model_validator

from fusion.api import Gate, GateDecision, Params

__all__ = ["Chi2Gate", "chi2_threshold", "n_sigma_threshold"]


@lru_cache(maxsize=256)
def chi2_threshold(probability: float, dim: int) -> float:
    """``chi2.ppf(probability, dim)``: the NIS a consistent filter's measurement of ``dim`` values stays under
    with that probability."""
    if dim < 1:
        raise ValueError(f"measurement dimension must be >= 1, got {dim}")
    from fusion.chisquare import chi2

    return float(chi2.ppf(probability, dim))


@lru_cache(maxsize=256)
def n_sigma_threshold(n_sigma: float, dim: int) -> float:
    """The NIS threshold of an n-sigma gate: ``n_sigma^2`` for a scalar, else the chi-square quantile of the
    same probability as the 1-D interval, computed on the upper tail's logarithm,
    ``isf_log(chi2.logsf(n_sigma^2, 1), dim)``
    (``ppf(cdf(...))`` loses the tail to rounding from ~8 sigma on: cdf rounds to 1 and the gate opens;
    the probability itself underflows beyond ~37 sigma)."""
    if dim < 1:
        raise ValueError(f"measurement dimension must be >= 1, got {dim}")
    if dim == 1:
        return float(n_sigma) ** 2
    from fusion.chisquare import chi2, isf_log

    return float(isf_log(chi2.logsf(float(n_sigma) ** 2, 1), dim))


class Chi2Gate(Gate):
    r"""Chi-square validation gate: accept a measurement of dimension m when

        NIS = y^T S^-1 y <= chi2.ppf(probability, m)

    (y the innovation, S its covariance; the NIS of a consistent filter is chi-square with m degrees
    of freedom). ``n_sigma`` instead gates a scalar measurement at |y| <= n_sigma sqrt(S), i.e.
    NIS <= n_sigma^2 (paper 003 rejects echoes at 2-3 sigma); for m > 1 it uses the same probability
    as the 1-D n-sigma interval (:func:`n_sigma_threshold`, finite up to n_sigma 1e3). Give one of the two
    (default probability 0.997).

    Memoryless and immutable: ``check`` returns the decision (fusion.api.GateDecision); the run counts
    them (``checked``, ``rejected``: fusion.api.GateRun).
    """

    name = "chi2"

    class Params(Params):
        """Gate threshold: a probability, or n_sigma for scalar measurements."""

        probability: float | None = Field(None, ge=1e-12, lt=1.0,
                                          description="probability mass inside the gate (e.g. 0.997)")
        n_sigma: float | None = Field(None, gt=0.0, le=1e3, description="gate at n standard deviations (scalars)")

        @model_validator(mode="after")
        def _one_of(self):
            if self.probability is not None and self.n_sigma is not None:
                raise ValueError("give probability or n_sigma, not both")
            if self.probability is None and self.n_sigma is None:
                self.probability = 0.997
            return self

    def threshold(self, dim: int) -> float:
        """The NIS threshold for a measurement of dimension ``dim``."""
        p = self.params
        try:
            if p.n_sigma is not None:
                return n_sigma_threshold(float(p.n_sigma), dim)
            return chi2_threshold(float(p.probability), dim)
        except ValueError as exc:
            raise ValueError(f"gate {self.name!r}: {exc}") from None

    def check(self, nis: float, dim: int, state: None = None) -> tuple[GateDecision, None]:
        """Accepted when NIS <= threshold(dim); a NaN NIS is refused."""
        th = self.threshold(dim)
        return GateDecision(bool(nis <= th), th), None
