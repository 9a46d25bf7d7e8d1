"""Batched filters: N independent filters advanced together over a leading axis.

``x`` (N, n), ``P`` or ``S`` (N, n, n); each filter has its own measurement, gate verdict, rejection
and covariance repair (boolean masks over N, never a Python loop over filters or sigma points in the hot
path). The numbers equal N single filters (plugins/filters/) to ~1e-12 (tests/batch/).

``make_batch_filter(flt)`` gives the batched counterpart of a wired single filter (kf, ekf, ukf, srukf)
with the same parameters. Models vectorise ``f`` and ``h`` over leading axes (DESIGN.md); the optional
``Q_batch``, ``jacobian_batch`` methods of a model give ``Q``, ``F`` and ``H`` for all N states at once,
otherwise :mod:`fusion.batch.models` falls back on one call per filter (correct, slower).
"""
from __future__ import annotations

from .belief import BatchBelief, BatchUpdate
from .filters import (BatchEKF, BatchFilter, BatchKF, BatchSRUKF, BatchUKF, batch_capable, make_batch_filter)

__all__ = ["BatchBelief", "BatchUpdate", "BatchFilter", "BatchKF", "BatchEKF", "BatchUKF", "BatchSRUKF",
           "make_batch_filter", "batch_capable"]
