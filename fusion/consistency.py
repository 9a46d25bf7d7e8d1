"""Filter consistency statistics: NEES and NIS against their chi-square intervals.

For a consistent filter the normalised estimation error squared
``NEES = e^T P^-1 e`` (``e = x_true - x_est``) and the normalised innovation squared
``NIS = y^T S^-1 y`` (innovation ``y``, innovation covariance ``S``) are chi-square distributed with as
many degrees of freedom as the error has components (Bar-Shalom, Li and Kirubarajan 2001, sec. 5.4).
Each step is tested against the two-sided 95% interval ``[chi2.ppf(0.025, dof), chi2.ppf(0.975, dof)]``;
about 95% of the steps of a consistent filter fall inside, and the mean is about ``dof``.

Used by fusion.metrics.ErrorTracker; the bounds are also drawn by fusion.sinks.plot.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from fusion.lapack import lapack
from fusion.chisquare import chi2

__all__ = ["chi2_interval", "nees", "ChiSquareStat", "NisTracker"]


@lru_cache(maxsize=256)
def chi2_interval(dof: int, prob: float = 0.95) -> tuple[float, float]:
    """Two-sided ``prob`` interval ``(lo, hi)`` of a chi-square variable with ``dof`` degrees of freedom.

    >>> lo, hi = chi2_interval(1)
    >>> round(lo, 5), round(hi, 4)
    (0.00098, 5.0239)
    """
    if dof < 1:
        raise ValueError(f"chi-square needs dof >= 1, got {dof}")
    tail = (1.0 - prob) / 2.0
    return float(chi2.ppf(tail, dof)), float(chi2.ppf(1.0 - tail, dof))


def nees(e: np.ndarray, P: np.ndarray) -> float:
    """``e^T P^-1 e`` for an error ``e`` (m,) and covariance ``P`` (m, m), by Cholesky and a triangular
    solve (never an explicit inverse). NaN when ``P`` is not positive definite or anything is non-finite."""
    e = np.ascontiguousarray(e, dtype=float)
    if e.size == 0:
        return math.nan
    # LAPACK directly: numpy.linalg's wrappers dominate at these sizes (DESIGN.md, performance).
    L, info = lapack.dpotrf(P, lower=1, clean=0)
    if info != 0:
        return math.nan
    w, info = lapack.dtrtrs(L, e, lower=1)
    if info != 0:
        return math.nan
    v = float(w @ w)
    return v if math.isfinite(v) else math.nan  # NaN/inf anywhere in e or P ends here


@dataclass
class ChiSquareStat:
    """Running mean of a chi-square statistic and the fraction of samples inside their 95% interval.

    Samples may have different ``dof`` (e.g. a sensor whose measurement size varies); each is tested
    against the interval of its own dof. ``dof`` reports the dof when it is the same for all samples, else
    the largest; ``mean`` is then no chi-square mean of any one dof (1-dof arrivals and a
    4-dof fix), and ``per_dof_mean`` (sum of the values over the sum of their dofs, about 1 for a consistent filter,
    with its interval ``per_dof_interval``) is the comparable one. Non-finite values are counted in
    ``skipped`` and otherwise ignored."""

    prob: float = 0.95
    count: int = 0
    total: float = 0.0
    inside: int = 0
    skipped: int = 0
    dofs: set[int] = field(default_factory=set)
    dof_total: int = 0

    def add(self, value: float, dof: int) -> bool | None:
        """Record one sample; returns whether it is inside its interval (None when skipped)."""
        if not math.isfinite(value) or dof < 1:
            self.skipped += 1
            return None
        lo, hi = chi2_interval(int(dof), self.prob)
        ok = lo <= value <= hi
        self.count += 1
        self.total += value
        self.inside += ok
        self.dofs.add(int(dof))
        self.dof_total += int(dof)
        return ok

    @property
    def mean(self) -> float | None:
        return self.total / self.count if self.count else None

    @property
    def in_fraction(self) -> float | None:
        return self.inside / self.count if self.count else None

    @property
    def dof(self) -> int | None:
        return max(self.dofs) if self.dofs else None

    @property
    def per_dof_mean(self) -> float | None:
        """``sum(values) / sum(dofs)``: about 1 for a consistent filter whatever the dofs."""
        return self.total / self.dof_total if self.dof_total else None

    def per_dof_interval(self) -> tuple[float, float] | None:
        """The ``prob`` interval of :attr:`per_dof_mean` for a consistent filter (independent samples: their
        sum is chi-square with ``dof_total`` dof), or None without samples."""
        if not self.dof_total:
            return None
        lo, hi = chi2_interval(self.dof_total, self.prob)
        return lo / self.dof_total, hi / self.dof_total


class NisTracker:
    """Per-sensor NIS: running statistics plus, optionally, the time series for plots.

    ``add(sensor, nis, dim, t=None, accepted=None)``; ``series()`` gives ``{sensor: (times (k,), values
    (k,), dim)}`` (the format fusion.sinks.plot.plot_run takes) when times were given. ``keep_series=False``
    keeps memory constant for very long runs. ``stats`` are over every sample; with ``accepted`` given, the
    accepted updates (``accepted_stats``, and per dof ``accepted_by_dof``) and the ones the gate rejected
    (``rejected_stats``) are kept apart as well."""

    def __init__(self, keep_series: bool = True, prob: float = 0.95):
        self.prob = prob
        self.keep_series = keep_series
        self.stats: dict[str, ChiSquareStat] = {}
        self.accepted_stats: dict[str, ChiSquareStat] = {}
        self.rejected_stats: dict[str, ChiSquareStat] = {}
        self.accepted_by_dof: dict[str, dict[int, ChiSquareStat]] = {}
        self._t: dict[str, list[float]] = {}
        self._v: dict[str, list[float]] = {}

    def add(self, sensor: str, nis: float, dim: int, t: float | None = None,
            accepted: bool | None = None) -> bool | None:
        st = self.stats.get(sensor)
        if st is None:
            st = self.stats[sensor] = ChiSquareStat(self.prob)
            self._t[sensor], self._v[sensor] = [], []
        ok = st.add(float(nis), int(dim))
        if accepted is not None:
            kind = self.accepted_stats if accepted else self.rejected_stats
            side = kind.get(sensor)
            if side is None:
                side = kind[sensor] = ChiSquareStat(self.prob)
            side.add(float(nis), int(dim))
            if accepted and ok is not None:
                by = self.accepted_by_dof.setdefault(sensor, {})
                one = by.get(int(dim))
                if one is None:
                    one = by[int(dim)] = ChiSquareStat(self.prob)
                one.add(float(nis), int(dim))
        if self.keep_series and t is not None and ok is not None:
            self._t[sensor].append(float(t))
            self._v[sensor].append(float(nis))
        return ok

    def series(self) -> dict[str, tuple[np.ndarray, np.ndarray, int]]:
        return {s: (np.asarray(self._t[s]), np.asarray(self._v[s]), st.dof or 1)
                for s, st in self.stats.items() if self._t[s]}

    def summary(self) -> dict:
        """``{"nis_mean": {sensor: mean}, "nis_in_95_fraction": {sensor: fraction}, "nis_dof": {...},
        "nis_samples": {...}}`` over the sensors with at least one finite sample, every update tried
        (accepted or rejected, dofs mixed: ``nis_dof`` is then the largest). When the updates were told
        accepted or not, also, per sensor:

        - ``nis_accepted_mean``, ``nis_accepted_in_95_fraction``, ``nis_accepted_samples``,
          ``nis_accepted_dofs`` (sorted list): the accepted updates;
        - ``nis_accepted_mean_per_dof`` (sum of NIS / sum of dofs: ~1 when consistent, comparable across
          dofs) and ``nis_accepted_mean_per_dof_95`` ([lo, hi], its 95% interval);
        - ``nis_accepted_by_dof`` (only sensors with several dofs): ``{dof: {"mean", "in_95_fraction",
          "samples"}}`` (dof as a string key);
        - ``nis_rejected_mean``, ``nis_rejected_samples``: the updates the gate rejected (the gate's own
          statistic; every sensor with a sample, 0 and None when none was rejected).
        """
        used = {s: st for s, st in sorted(self.stats.items()) if st.count}
        out: dict = {
            "nis_mean": {s: st.mean for s, st in used.items()},
            "nis_in_95_fraction": {s: st.in_fraction for s, st in used.items()},
            "nis_dof": {s: st.dof for s, st in used.items()},
            "nis_samples": {s: st.count for s, st in used.items()},
        }
        told = [s for s in used if s in self.accepted_stats or s in self.rejected_stats]
        if not told:
            return out
        acc = {s: self.accepted_stats[s] for s in told if s in self.accepted_stats and self.accepted_stats[s].count}
        rej = {s: self.rejected_stats.get(s) or ChiSquareStat(self.prob) for s in told}
        out.update(
            nis_accepted_mean={s: st.mean for s, st in acc.items()},
            nis_accepted_in_95_fraction={s: st.in_fraction for s, st in acc.items()},
            nis_accepted_samples={s: st.count for s, st in acc.items()},
            nis_accepted_dofs={s: sorted(st.dofs) for s, st in acc.items()},
            nis_accepted_mean_per_dof={s: st.per_dof_mean for s, st in acc.items()},
            nis_accepted_mean_per_dof_95={s: list(st.per_dof_interval() or ()) for s, st in acc.items()},
            nis_accepted_by_dof={s: {str(d): {"mean": b.mean, "in_95_fraction": b.in_fraction, "samples": b.count}
                                     for d, b in sorted(self.accepted_by_dof[s].items())}
                                 for s, st in acc.items() if len(st.dofs) > 1},
            nis_rejected_mean={s: st.mean for s, st in rej.items()},
            nis_rejected_samples={s: st.count for s, st in rej.items()},
        )
        return out
