"""reopening: an n-sigma validation gate that opens when almost everything is rejected (paper 003 sec. 4.2,
re-opening rule after the Crazyflie LPS TDoA outlier filter)."""
from __future__ import annotations

from typing import NamedTuple

from pydantic import Field, model_validator

from fusion.api import Gate, GateDecision, Params
from fusion_plugins.gates.chi2 import n_sigma_threshold

__all__ = ["ReopeningGate", "ReopeningState"]

_OPEN = GateDecision(True, float("inf"), ("accepted_open",))
_OPEN_NAN = GateDecision(False, float("inf"))


class ReopeningState(NamedTuple):
    """The gate's memory in one run: ``is_open`` and the ``integrator`` of the recent fit (0 to window)."""

    is_open: bool
    integrator: float


class ReopeningGate(Gate):
    r"""n-sigma gate with a re-opening rule.

    Closed, it accepts a measurement of dimension m when its NIS ``y^T S^-1 y <= n_sigma^2`` (m = 1: the
    innovation within n_sigma standard deviations; paper 003 gates arrival times at 2 sigma of 0.2 ms and
    so rejects echoes, whose extra path of 0.3-3 m is 4-40 sigma). For m > 1 the threshold is the chi-square
    quantile of the same probability (chi2.n_sigma_threshold: on the upper tail, finite far out).

    A gate alone can lock a filter out: once the belief is wrong (a bad start, a jump, a run of echoes
    accepted), the truth itself falls outside the gate and is rejected for ever. As in the Crazyflie's
    ``outlierFilterTdoaValidateIntegrator`` (bitcraze/crazyflie-firmware, src/modules/src/outlierfilter),
    an integrator counts the recent fit: each measurement with NIS within ``trigger_sigma^2`` (default
    n_sigma) adds 1, any other subtracts 1, clamped to ``[0, window]``. Closed, the gate opens when the
    integrator falls below ``open_fraction * window`` (almost everything rejected: the filter has likely
    diverged) and then accepts every measurement; open, it closes again once the integrator is above
    ``close_fraction * window`` (samples fit again). It starts closed with a full integrator (the filter's
    initial covariance is wide, so early samples fit); ``start_open`` starts it open and empty, as the
    Crazyflie does at start-up.

    The gate itself is immutable: its memory is a :class:`ReopeningState` value (fusion.api.KeepsGateState),
    kept by the run. Decisions' reasons, counted by the run besides ``checked`` and ``rejected``:
    ``opened`` (the gate re-opened), ``closed``, ``accepted_open`` (let through while open).
    """

    name = "reopening"

    class Params(Params):
        n_sigma: float = Field(2.0, gt=0.0, le=1e3, description="gate at n standard deviations (paper 003: 2)")
        trigger_sigma: float | None = Field(None, gt=0.0, le=1e3, description="a sample 'fits' the integrator within "
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

    def initial_state(self) -> ReopeningState:
        """Closed with a full integrator, or open and empty with ``start_open``."""
        p = self.params
        return ReopeningState(True, 0.0) if p.start_open else ReopeningState(False, float(p.window))

    def threshold(self, dim: int, n_sigma: float | None = None) -> float:
        """NIS threshold of an n-sigma gate (default this gate's n_sigma) for dimension ``dim``."""
        try:
            return n_sigma_threshold(float(self.params.n_sigma if n_sigma is None else n_sigma), dim)
        except ValueError as exc:
            raise ValueError(f"gate {self.name!r}: {exc}") from None

    def check(self, nis: float, dim: int, state: ReopeningState | None = None
              ) -> tuple[GateDecision, ReopeningState]:
        """The decision and the next state (``state`` None: the initial one). A NaN NIS never passes and
        never fits."""
        p = self.params
        is_open, integrator = state if state is not None else self.initial_state()
        fits = bool(nis <= self.threshold(dim, p.trigger_sigma))
        integrator = min(integrator + 1.0, p.window) if fits else max(integrator - 1.0, 0.0)
        if is_open:
            closes = integrator > p.close_fraction * p.window
            if nis == nis:                      # everything but NaN passes while open
                decision = _OPEN if not closes else GateDecision(True, float("inf"), ("accepted_open", "closed"))
            else:
                decision = _OPEN_NAN if not closes else GateDecision(False, float("inf"), ("closed",))
            return decision, ReopeningState(not closes, integrator)
        th = self.threshold(dim)
        ok = bool(nis <= th)
        if integrator < p.open_fraction * p.window:
            return GateDecision(ok, th, ("opened",)), ReopeningState(True, integrator)
        return GateDecision(ok, th), ReopeningState(False, integrator)
