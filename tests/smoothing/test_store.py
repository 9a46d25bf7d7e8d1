"""The disk-backed chunk store: order both ways, spilling past the memory budget, cleanup."""
from __future__ import annotations

import numpy as np

from fusion.smoothing.store import ChunkStore


def _fill(store, k):
    rng = np.random.default_rng(0)
    rows = [(float(i), rng.standard_normal(3), rng.standard_normal((3, 3))) for i in range(k)]
    for t, x, P in rows:
        store.append(t=t, x=x, P=P)
    return rows


def test_order_forward_and_reversed_across_chunks():
    s = ChunkStore(chunk=7, disk=False)
    rows = _fill(s, 50)
    fwd = list(s.forward_rows())
    rev = list(s.rows_reversed())
    assert len(s) == len(fwd) == len(rev) == 50
    for (t, x, P), r in zip(rows, fwd):
        assert r["t"] == t and np.array_equal(r["x"], x) and np.array_equal(r["P"], P)
    assert [r["t"] for r in rev] == [r[0] for r in reversed(rows)]
    assert not s.on_disk and s.bytes_on_disk == 0


def test_spills_to_disk_past_the_budget_and_cleans_up():
    s = ChunkStore(chunk=8, disk=None, memory_bytes=2000)
    rows = _fill(s, 100)
    assert s.on_disk and s.bytes_on_disk > 0
    # every sealed chunk is on disk: memory holds at most the open chunk
    assert all(not isinstance(c, dict) for c in s._chunks)
    assert [r["t"] for r in s.rows_reversed()] == [r[0] for r in reversed(rows)]
    d = s._dir
    assert d.exists()
    s.close()
    assert not d.exists()


def test_disk_true_spills_from_the_first_chunk():
    s = ChunkStore(chunk=4, disk=True)
    _fill(s, 5)
    assert s.on_disk
    s.close()
