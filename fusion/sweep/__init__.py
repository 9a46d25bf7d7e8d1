"""``fusion sweep``: many seeded trials (simulate a scenario, run a config variant) over seeds x filters x
parameters, one row a trial, with a summary over the seeds (docs/sweep.md).

* :mod:`fusion.sweep.trial`: a trial and its row (a pure function of config, scenario, seed, params);
* :mod:`fusion.sweep.engines`: where trials run (batched in process, serial, a process pool, Dask);
* :mod:`fusion.sweep.batched`: the batched engine (fusion.batch filters, the pipeline's RunStats);
* :mod:`fusion.sweep.results`: CSV / Parquet results files, resuming;
* :mod:`fusion.sweep.stats`: means with confidence intervals, paired Wilcoxon comparisons;
* :mod:`fusion.sweep.grid`: the trials of a command line, :func:`fusion.sweep.grid.sweep` the API.
"""
from __future__ import annotations

__all__ = ["Trial", "run_trial", "sweep"]


def __getattr__(name: str):
    if name in ("Trial", "run_trial"):
        from . import trial
        return getattr(trial, name)
    if name == "sweep":
        from .grid import sweep
        return sweep
    raise AttributeError(name)
