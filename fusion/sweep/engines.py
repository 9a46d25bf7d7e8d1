"""Where the trials of a sweep run: ``batch`` (in process, the seeds of a variant through one batched
filter), ``serial`` (in process, one trial after another through the pipeline), ``pool`` (a local
process pool, concurrent.futures) or ``dask`` (dask.distributed: a LocalCluster, or a running scheduler
at ``tcp://HOST:8786``). Every engine yields ``(trial, row)`` as trials finish; a trial is a pure
function of its fields, so the rows do not depend on the engine (tests/sweep/test_engines.py)."""
from __future__ import annotations

import multiprocessing
import multiprocessing.pool
import os
import signal
import threading
import time
from collections import defaultdict
from contextlib import contextmanager
from typing import Any, Iterator

from fusion.api import ConfigError

from .trial import Trial, run_trial

__all__ = ["run_serial", "run_pool", "run_dask", "run_batched", "batch_ready", "dask_client", "ENGINES"]

ENGINES = ("auto", "batch", "serial", "pool", "dask")


def _threads_one() -> None:
    """Single-threaded BLAS in workers (tiny matrices: threads only add latency; fusion/cli.py does the same)."""
    for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(v, "1")


def _worker_init() -> None:
    """A pool worker: single-threaded BLAS; Ctrl-C is the parent's (a terminal sends SIGINT to the whole
    process group: the parent stops the pool and keeps the rows so far, a worker must not die mid-trial
    and break the pool); and the worker exits when its parent is gone (a killed sweep leaves no orphans)."""
    _threads_one()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent = os.getppid()

    def watch_parent() -> None:
        while True:
            time.sleep(1.0)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch_parent, name="fusion-watch-parent", daemon=True).start()


@contextmanager
def _pool(jobs: int) -> Iterator[multiprocessing.pool.Pool]:
    """A process pool that, when the sweep is interrupted (Ctrl-C, an error, the consumer closing the
    generator), stops its workers at once (``Pool.terminate``) instead of finishing every submitted trial
    first, which is what ``with ProcessPoolExecutor`` does (its exit is ``shutdown(wait=True)``; and a
    ``shutdown(cancel_futures=True)`` still leaves the running trials to wait for at interpreter exit)."""
    pool = multiprocessing.Pool(processes=jobs, initializer=_worker_init)
    try:
        yield pool
    except BaseException:
        pool.terminate()
        pool.join()
        raise
    pool.close()
    pool.join()


def _trial_row(trial: Trial) -> tuple[Trial, dict[str, Any]]:
    return trial, run_trial(trial)


def run_serial(trials: list[Trial]) -> Iterator[tuple[Trial, dict[str, Any]]]:
    for t in trials:
        yield t, run_trial(t)


def run_pool(trials: list[Trial], jobs: int) -> Iterator[tuple[Trial, dict[str, Any]]]:
    """A local process pool of ``jobs`` workers."""
    _threads_one()
    with _pool(jobs) as pool:
        yield from pool.imap_unordered(_trial_row, trials)


def dask_client(where: str, jobs: int):
    """A dask.distributed Client: ``local`` starts a LocalCluster of ``jobs`` single-threaded worker
    processes; otherwise ``where`` is a scheduler address (tcp://HOST:8786). ConfigError when dask is
    not installed."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise ConfigError("--dask/--scheduler need dask.distributed: pip install 'fusion-estimator[cluster]' "
                          "(or pip install 'dask[distributed]')") from None
    if where == "local":
        import logging
        cluster = LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=logging.ERROR)
        return Client(cluster)
    try:
        return Client(where, timeout="10s")
    except OSError as exc:
        raise ConfigError(f"--scheduler {where}: cannot reach a dask scheduler there ({exc})") from None


def run_dask(trials: list[Trial], client) -> Iterator[tuple[Trial, dict[str, Any]]]:
    """Each trial a dask task on the client's cluster (the package must be importable on the workers)."""
    from dask.distributed import as_completed as dask_completed

    client.run(_threads_one)
    futs = client.map(run_trial, trials, pure=False)
    which = {f.key: t for f, t in zip(futs, trials)}
    for f in dask_completed(futs):
        yield which[f.key], f.result()


def batch_ready(trials: list[Trial]) -> tuple[list[list[Trial]], list[Trial], dict[str, str]]:
    """Split trials into batchable groups (one variant each, its seeds) and the rest, with the reason
    per variant that is not batchable (wiring each variant once)."""
    from .batched import unsupported
    from .trial import system_of

    groups: dict[tuple, list[Trial]] = defaultdict(list)
    for t in trials:
        groups[t.variant()].append(t)
    ready, rest, why = [], [], {}
    for var, ts in groups.items():
        reason = unsupported(system_of(ts[0]), ts[0])
        if reason is None:
            ready.append(ts)
        else:
            why[str(var)] = reason
            rest.extend(ts)
    return ready, rest, why


def _batch_part(part: list[Trial]) -> list[tuple[Trial, dict[str, Any]]]:
    """One chunk of one variant's seeds through the batched engine; a chunk not in lockstep falls back on
    the pipeline, trial by trial (its rows say so); an error of the whole chunk is every trial's row."""
    from .batched import NotLockstep, run_batch

    _threads_one()
    try:
        return list(zip(part, run_batch(part)))
    except NotLockstep:
        return [(t, run_trial(t)) for t in part]
    except Exception as exc:
        msg = f"{type(exc).__name__}: {exc}".replace("\n", " ")[:500]
        return [(t, {"status": "error", "error": msg, "engine": "batch"}) for t in part]


def run_batched(groups: list[list[Trial]], chunk: int = 256, jobs: int = 1) -> Iterator[tuple[Trial, dict[str, Any]]]:
    """Each group (one variant) in chunks of at most ``chunk`` seeds through the batched engine: in this
    process (``jobs`` 1), or the chunks spread over a pool of ``jobs`` processes (each group then split
    into at least ``jobs`` chunks so that every core batches)."""
    parts = []
    for ts in groups:
        size = min(chunk, max(1, -(-len(ts) // jobs)))
        parts += [ts[i:i + size] for i in range(0, len(ts), size)]
    if jobs <= 1 or len(parts) == 1:
        for part in parts:
            yield from _batch_part(part)
        return
    _threads_one()
    with _pool(jobs) as pool:
        for rows in pool.imap_unordered(_batch_part, parts):
            yield from rows
