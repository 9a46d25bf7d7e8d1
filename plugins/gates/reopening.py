"""reopening: an n-sigma validation gate that opens when almost everything is rejected (paper 003 sec. 4.2,
re-opening rule after the Crazyflie LPS TDoA outlier filter)."""
from __future__ import annotations

from pydantic import Field, model_validator

from fusion.api import Gate, Params


class ReopeningGate(Gate):
    r"""n-sigma gate with a re-opening rule.

    Closed, it accepts a measurement of dimension m when its NIS ``y^T S^-1 y <= n_sigma^2`` (m = 1: the
    innovation within n_sigma standard deviations; paper 003 gates arrival times at 2 sigma of 0.2 ms and
    so rejects echoes, whose extra path of 0.3-3 m is 4-40 sigma). For m > 1 the threshold is the chi-square
    quantile of the same probability, ``chi2.ppf(chi2.cdf(n_sigma^2, 1), m)``.

    A gate alone can lock a filter out: once the belief is wrong (a bad start, a jump, a run of echoes
    accepted), the truth itself falls outside the gate and is rejected for ever. As in the Crazyflie's
    ``outlierFilterTdoaValidateIntegrator`` (bitcraze/crazyflie-firmware, src/modules/src/outlierfilter),
    an integrator counts the recent fit: each measurement with NIS within ``trigger_sigma^2`` (default
    n_sigma) adds 1, any other subtracts 1, clamped to ``[0, window]``. Closed, the gate opens when the
    integrator falls below ``open_fraction * window`` (almost everything rejected: the filter has likely
    diverged) and then accepts every measurement; open, it closes again once the integrator is above
    ``close_fraction * window`` (samples fit again). It starts closed with a full integrator (the filter's
    initial covariance is wide, so early samples fit); ``start_open`` starts it open and empty, as the
    Crazyflie does at start-up. Counters: ``checked``, ``rejected`` (refused while closed), ``opened``
    (times the gate re-opened), ``accepted_open`` (measurements let through while open).
    """

    name = "reopening"

    class Params(Params):
        n_sigma: float = Field(2.0, gt=0.0, description="gate at n standard deviations (paper 003: 2)")
        trigger_sigma: float | None = Field(None, gt=0.0, description="a sample 'fits' the integrator within "
                                            "this many sd (default n_sigma)")
        window: int = Field(40, ge=2, description="integrator size (measurements): about how many mostly "
                            "rejected samples it takes to open, and fitting ones to close")
        open_fraction: float = Field(0.1, ge=0.0, lt=1.0, description="open below this fraction of window")
        close_fraction: float = Field(0.9, gt=0.0, le=1.0, description="close above this fraction of window")
        start_open: bool = Field(False, description="start open with an empty integrator (Crazyflie)")

        @model_validator(mode="after")
        def _levels(self):
            if self.open_fraction >= self.close_fraction:
                raise ValueError(f"open_fraction ({self.open_fraction}) must be below close_fraction "
                                 f"({self.close_fraction})")
            return self

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        p = self.params
        self.checked = 0
        self.rejected = 0
        self.opened = 0
        self.accepted_open = 0
        self.is_open = p.start_open
        self.integrator = 0.0 if p.start_open else float(p.window)
        self._thresholds: dict[tuple[int, float], float] = {}

    def threshold(self, dim: int, n_sigma: float | None = None) -> float:
        """NIS threshold of an n-sigma gate (default this gate's n_sigma) for dimension ``dim``."""
        ns = self.params.n_sigma if n_sigma is None else n_sigma
        key = (dim, ns)
        th = self._thresholds.get(key)
        if th is None:
            if dim < 1:
                raise ValueError(f"gate {self.name!r}: measurement dimension must be >= 1, got {dim}")
            if dim == 1:
                th = ns ** 2
            else:
                from fusion.chisquare import chi2
                th = float(chi2.ppf(chi2.cdf(ns ** 2, 1), dim))
            self._thresholds[key] = th
        return th

    def accept(self, nis: float, dim: int) -> bool:
        """True when the measurement passes; updates the integrator and the open/closed state. A NaN NIS
        never passes and never fits."""
        p = self.params
        self.checked += 1
        fits = bool(nis <= self.threshold(dim, p.trigger_sigma))
        self.integrator = min(self.integrator + 1.0, p.window) if fits else max(self.integrator - 1.0, 0.0)
        if self.is_open:
            if self.integrator > p.close_fraction * p.window:
                self.is_open = False
            ok = bool(nis == nis)               # everything but NaN passes while open
            self.accepted_open += ok
            return ok
        ok = bool(nis <= self.threshold(dim))
        if not ok:
            self.rejected += 1
        if self.integrator < p.open_fraction * p.window:
            self.is_open = True
            self.opened += 1
        return ok
