"""``health:`` in a system YAML: the limits past which a finished run's estimate is judged untrustworthy
(fusion.health.rule), ``fusion run`` then ending with exit code 4 (DEGRADED_EXIT)::

    health:
      allow_degraded: false        # true: report, but exit 0 (as --allow-degraded)
      max_unused_share: 0.5        # a measurement sensor rejected or late-dropped for more of its messages
      lockout_s: null              # s of rejections in a row; null: the sensor's recovery.after_s (see below)
      nis_false_alarm: 1.0e-3      # chance that a consistent filter's run is flagged by the NIS test
      nis_min_ratio: 2.0           # and a window's NIS per dof over this
      nis_window_dof: 100          # a NIS window closes when its updates' dofs add up to this
      truth: {nees_per_dof: 10}    # errors against truth lines beyond any of these
      reference: {attitude_rmse_deg: 30}   # agreement with reference lines beyond any of these
"""
from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["HealthSpec", "AgreementLimits", "TruthLimits", "ReferenceLimits", "DEGRADED_EXIT"]

#: The exit code of a run whose estimate cannot be trusted (after 3, a non-finite estimate).
DEGRADED_EXIT = 4


class AgreementLimits(BaseModel):
    """Limits on the errors against ``truth`` lines (or the agreement with ``reference`` lines): the run is
    degraded when any given one is exceeded. Units: m, m/s, deg; ``nees_per_dof`` the NEES mean over its
    dof (about 1 for a consistent filter; truth only)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    position_rmse_m: float | None = Field(None, gt=0.0)
    position_max_m: float | None = Field(None, gt=0.0)
    velocity_rmse_mps: float | None = Field(None, gt=0.0)
    attitude_rmse_deg: float | None = Field(None, gt=0.0)
    attitude_max_deg: float | None = Field(None, gt=0.0)
    nees_per_dof: float | None = Field(None, gt=1.0)


class TruthLimits(AgreementLimits):
    """``health.truth``: by default the NEES mean at most 10 per dof, an order of magnitude over a consistent
    filter's 1 (the covariance understating the error ~3x in sd), unless at least ``nees_inside_min`` of the
    estimates' NEES are inside their 95 % interval (the mean made by a few samples, e.g. a bad truth line,
    is no persistent inconsistency)."""

    nees_per_dof: float | None = Field(10.0, gt=1.0)
    nees_inside_min: float = Field(0.5, gt=0.0, le=1.0)


class ReferenceLimits(AgreementLimits):
    """``health.reference``: another estimator is no truth and comes without a covariance here, so by
    default only a gross attitude disagreement (RMSE over 30 deg) counts."""

    attitude_rmse_deg: float | None = Field(30.0, gt=0.0)


class HealthSpec(BaseModel):
    """``health:`` (see the module)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    allow_degraded: bool = Field(False, description="a degraded run still exits 0 (as --allow-degraded)")
    max_unused_share: float = Field(0.5, gt=0.0, lt=1.0, description="share of a measurement sensor's messages "
                                    "rejected or dropped as late past which the run is degraded")
    lockout_s: float | None = Field(None, gt=0.0, description="s of a sensor's updates rejected in a row past "
                                    "which the run is degraded; null: its recovery's after_s when it has one, "
                                    "else only a lock-out that lasts to the end of its messages (at least 2 s) "
                                    "or over max_unused_share of its span")
    nis_false_alarm: float = Field(1e-3, gt=0.0, lt=0.5, description="probability that a consistent filter's "
                                   "run is flagged by the NIS window test")
    nis_min_ratio: float = Field(2.0, ge=1.0, description="a NIS window counts as beyond only when its NIS per dof "
                                 "is also over this (innovations sqrt(2) times what the filter predicts): a mild "
                                 "mis-tuning is significant on long runs, and no reason to distrust the estimate")
    nis_window_dof: int = Field(100, ge=10, le=100_000, description="a NIS window closes when the dofs of its "
                                "accepted updates add up to this")
    min_messages: int = Field(5, ge=1, description="a sensor with fewer decided messages is not judged by its "
                              "shares")
    truth: TruthLimits = Field(default_factory=TruthLimits)
    reference: ReferenceLimits = Field(default_factory=ReferenceLimits)
