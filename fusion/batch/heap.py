"""Keep freed memory in the process heap while batches run (glibc only; elsewhere nothing happens).

A batched step allocates and frees temporaries of megabytes (1000 filters x 33 sigma points x 16
states is 4.2 MB an array). With glibc's defaults such blocks are either mmapped or trimmed off the top of
the heap when freed, so the next step's arrays are fresh pages: every element written first costs a page
fault; raising both thresholds avoids those faults (benchmarks/bench_batch.py measures the gain on the
16-state INS UKF over 1000 filters). The cost: the process keeps its peak heap (it is not returned to the
system until exit), which for a sweep or a benchmark is the working set it needs again at the next step anyway.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

__all__ = ["keep_heap", "HEAP_KEEP_BYTES"]

#: Blocks below this come from the heap, and the heap is not trimmed until this much is free at its top.
HEAP_KEEP_BYTES = 256 << 20
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3     # glibc malloc.h
_done: list[bool] = []


def keep_heap() -> bool:
    """Raise glibc's mmap and trim thresholds to HEAP_KEEP_BYTES once per process (True when set).
    ``FUSION_BATCH_KEEP_HEAP=0`` in the environment turns it off."""
    if _done:
        return _done[0]
    ok = False
    if sys.platform.startswith("linux") and os.environ.get("FUSION_BATCH_KEEP_HEAP", "1") != "0":
        try:
            libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
            ok = bool(libc.mallopt(_M_MMAP_THRESHOLD, HEAP_KEEP_BYTES)) and \
                bool(libc.mallopt(_M_TRIM_THRESHOLD, HEAP_KEEP_BYTES))
        except (OSError, AttributeError):            # not glibc (musl has no mallopt)
            ok = False
    _done.append(ok)
    return ok
