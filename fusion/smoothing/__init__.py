"""Offline and fixed-lag Rauch-Tung-Striebel smoothing of a run (``fusion run CONFIG --smooth``).

* :func:`run_smoothed` (``run.py``): the forward pass through ``fusion.pipeline`` with the filter
  recorded, then the backward pass; the sinks get the smoothed estimates, the summary gains ``smoothed``.
* ``record.py``: the recorded chain of nodes and transitions (``RecordingFilter``, ``ForwardLog``).
* ``backward.py``: the backward recursion, full and fixed-lag.
* ``store.py``: the disk-backed chunk store of the records (flat memory on long runs).
* ``protocol.py``: the capability a third-party filter declares (``rts_backend()``).
* The per-filter math (gains, cross-covariances, square-root form): ``fusion_plugins.filters.rts``.
"""
from __future__ import annotations

from .run import run_smoothed, smoother_backend

__all__ = ["run_smoothed", "smoother_backend"]
