"""A disk-backed, append-only store of fixed-shape records, read back in chunks (forward or reverse).

The forward pass of a smoother appends one record per transition (means, covariance factors, gains);
the backward pass reads them last to first. Records are buffered in a chunk of ``chunk`` rows (numpy
arrays, one per field), fewer when a chunk would pass ``chunk_bytes`` (256 KiB: a 16-state smoother's
transition is 4.4 kB, so 58 rows); a full chunk is kept in memory while the store holds less than
``memory_bytes``, and from then on every chunk (those already kept too) is written with ``np.save`` to
a temporary directory and read back as a read-only memory map. So memory stays bounded by one chunk
plus ``memory_bytes`` (1 MiB) whatever the length of the run, and a run long enough to spill at all
(a few minutes of the 16-state INS) already sits at that bound; ``disk=True`` spills from the first chunk,
``disk=False`` never spills. ``close()`` deletes the directory.
"""
from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import Iterator

import numpy as np

__all__ = ["ChunkStore"]


class ChunkStore:
    """Append-only records of named fields with fixed shapes (set by the first ``append``).

    :param chunk: rows a chunk at most.
    :param chunk_bytes: bytes a chunk at most (fewer rows for wide records; at least one row).
    :param disk: True: chunks go to disk; False: kept in memory; None: in memory up to ``memory_bytes``.
    :param memory_bytes: the in-memory budget of ``disk=None``.
    :param directory: where the temporary directory is made (default: the system's temp dir).
    """

    def __init__(self, chunk: int = 1024, disk: bool | None = None, memory_bytes: int = 1 << 20,
                 directory: str | Path | None = None, prefix: str = "fusion-smooth-", chunk_bytes: int = 256 << 10):
        if chunk < 1:
            raise ValueError("chunk must be >= 1")
        self.chunk = int(chunk)
        self.chunk_bytes = int(chunk_bytes)
        self.disk = disk
        self.memory_bytes = int(memory_bytes)
        self.directory = directory
        self.prefix = prefix
        self._fields: dict[str, tuple[tuple[int, ...], np.dtype]] | None = None
        self._buf: dict[str, np.ndarray] = {}
        self._fill = 0
        self._chunks: list[dict[str, np.ndarray] | tuple[Path, int]] = []  # in memory, or (file stem, rows)
        self._dir: Path | None = None
        self._mem = 0
        self.rows = 0
        self.bytes_on_disk = 0

    def __len__(self) -> int:
        return self.rows

    def __deepcopy__(self, memo) -> "ChunkStore":
        return self  # shared by the copies a scheduler makes of the components that hold it

    @property
    def on_disk(self) -> bool:
        return self._dir is not None

    def append(self, **values) -> None:
        """One record; every call gives the same fields with the same shapes."""
        if self._fields is None:
            self._fields = {}
            for k, v in values.items():
                a = np.asarray(v)
                self._fields[k] = (a.shape, a.dtype if a.dtype.kind in "iub" else np.dtype(float))
            row = sum(int(np.prod(shape, dtype=np.int64)) * dt.itemsize for shape, dt in self._fields.values())
            self.chunk = max(1, min(self.chunk, self.chunk_bytes // max(row, 1)))
            self._new_buffer()
        buf, i = self._buf, self._fill
        for k, v in values.items():
            buf[k][i] = v
        self._fill = i + 1
        self.rows += 1
        if self._fill == self.chunk:
            self._seal()

    def _new_buffer(self) -> None:
        assert self._fields is not None
        self._buf = {k: np.empty((self.chunk, *shape), dtype) for k, (shape, dtype) in self._fields.items()}
        self._fill = 0

    def _spill_to_disk(self) -> bool:
        if self.disk is True:
            return True
        if self.disk is False:
            return False
        return self._dir is not None or self._mem > self.memory_bytes

    def _seal(self) -> None:
        """Move the full (or, at the end, partial) buffer into the list of chunks."""
        rows = self._fill
        if rows == 0:
            return
        data = {k: (v if rows == self.chunk else v[:rows].copy()) for k, v in self._buf.items()}
        self._chunks.append(data)
        self._mem += sum(a.nbytes for a in data.values())
        if self._spill_to_disk():
            for j, c in enumerate(self._chunks):
                if isinstance(c, dict):
                    self._chunks[j] = self._write(j, c)
            self._mem = 0
        self._new_buffer()

    def _write(self, j: int, data: dict[str, np.ndarray]) -> tuple[Path, int]:
        if self._dir is None:
            self._dir = Path(tempfile.mkdtemp(prefix=self.prefix, dir=self.directory))
        stem = self._dir / f"{j:07d}"
        rows = 0
        for k, a in data.items():
            path = stem.with_name(f"{stem.name}_{k}.npy")
            np.save(path, a)
            self.bytes_on_disk += path.stat().st_size
            rows = a.shape[0]
        return stem, rows

    def _load(self, c) -> dict[str, np.ndarray]:
        if isinstance(c, dict):
            return c
        stem, _ = c
        assert self._fields is not None
        return {k: np.load(stem.with_name(f"{stem.name}_{k}.npy"), mmap_mode="r") for k in self._fields}

    def _all(self) -> list:
        out = list(self._chunks)
        if self._fill:
            out.append({k: v[:self._fill] for k, v in self._buf.items()})
        return out

    def chunks(self) -> Iterator[dict[str, np.ndarray]]:
        """The records in order, a chunk (a dict of arrays with a leading row axis) at a time."""
        for c in self._all():
            yield self._load(c)

    def reversed_chunks(self) -> Iterator[dict[str, np.ndarray]]:
        """The chunks last to first (rows within a chunk still in order: read them backwards)."""
        for c in reversed(self._all()):
            yield self._load(c)

    def rows_reversed(self) -> Iterator[dict[str, np.ndarray]]:
        """Every record, last to first, as a dict of arrays."""
        for c in self.reversed_chunks():
            n = next(iter(c.values())).shape[0]
            for i in range(n - 1, -1, -1):
                yield {k: v[i] for k, v in c.items()}

    def forward_rows(self) -> Iterator[dict[str, np.ndarray]]:
        """Every record in order, as a dict of arrays."""
        for c in self.chunks():
            n = next(iter(c.values())).shape[0]
            for i in range(n):
                yield {k: v[i] for k, v in c.items()}

    def close(self) -> None:
        """Forget the records and delete the temporary directory."""
        self._chunks = []
        self._buf = {}
        self._fill = 0
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None
