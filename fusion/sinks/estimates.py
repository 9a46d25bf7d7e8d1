"""Sink ``estimates``: every estimate as one row of a CSV (``.csv``) or JSON Lines (``.jsonl``) file.

Columns: ``t`` (s), every state element by name (``StateLayout.names``: ``px py pz vx .. qw qx ..``, SI
units, NED / body-to-NED quaternion as in the state), ``sd_<name>`` its standard deviation
(sqrt of the diagonal of P), ``reason`` (``update`` or ``output``) and ``sensor`` (the updating sensor,
empty for an output). CSV has a header line first (written when the file is opened, so even a run that
stops at once leaves a valid file); JSON Lines has one object per line with the same keys, non-finite
numbers as ``null``. The file is line-buffered: every row is on disk as soon as it is written, under a
temporary name beside the target (``.NAME.XXXX.tmp``) that is renamed to NAME when the run ends, so a
run that crashes keeps everything it produced and a finished file is never half-written. ``-``, a FIFO or
a device is written in place (fusion.outputs). Every write goes through fusion.outputs.OutputFile: a failed
one (a full disk, ``/dev/full``) removes the temporary file and is a FusionError naming the path (exit 2);
standard output closed by its reader (``-o - | head``) is fusion.outputs.StdoutClosed.

Built directly as ``EstimateWriter(path, layout)`` or from a config as the registered sink
``estimates`` (``EstimateWriter(params, context)`` with ``Params(path=..)`` and ``context.layout``).
"""
from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path
from typing import Literal

from pydantic import Field

from fusion.api import BuildContext, Estimate, FusionError, Params, Sink, StateLayout
from fusion.outputs import OutputFile

__all__ = ["EstimateWriter", "format_for"]

_JSONL = {".jsonl", ".ndjson"}


def format_for(path: str | os.PathLike, fmt: str = "auto") -> str:
    """``csv`` or ``jsonl`` for ``path`` (by suffix when ``fmt`` is ``auto``)."""
    if fmt in ("csv", "jsonl"):
        return fmt
    if fmt != "auto":
        raise FusionError(f"estimate output format {fmt!r}: expected auto, csv or jsonl")
    suffix = Path(str(path)).suffix.lower()
    if suffix in _JSONL:
        return "jsonl"
    if suffix == ".json":
        raise FusionError(f"{path}: estimates are written as CSV (.csv) or JSON Lines (.jsonl), not .json")
    return "csv"


class EstimateWriter(Sink):
    """Writes each estimate as a row: ``t``, the state by element name, ``sd_<name>``, ``reason``, ``sensor``.
    CSV or JSON Lines by the file suffix (``.csv``/``.jsonl``); line-buffered (flushed every row)."""

    name = "estimates"
    kind = "sink"
    suffixes = (".csv", ".jsonl", ".ndjson")

    @classmethod
    def for_path(cls, path: str, layout: StateLayout) -> "EstimateWriter":
        return cls(path, layout)

    class Params(Params):
        path: str = Field(description="output file: .csv or .jsonl (- for stdout)")
        format: Literal["auto", "csv", "jsonl"] = Field("auto", description="auto chooses by the suffix")

    def __init__(self, path, layout: StateLayout | None = None, fmt: str = "auto"):
        if isinstance(path, Params):  # built by the registry: cls(params, context)
            params = path
            context = layout if isinstance(layout, BuildContext) else BuildContext()
            super().__init__(params, context)
            path, layout, fmt = params.path, context.layout, params.format  # type: ignore[attr-defined]
        else:
            super().__init__(self.Params(path=str(path), format=fmt))  # type: ignore[call-arg]
        self.path = str(path)
        self.format = format_for(self.path, fmt)
        self.layout = layout
        self.rows = 0
        self._columns: list[str] | None = None
        self._owns = self.path != "-"
        # A regular file is written under a temporary name and renamed when the run closes it; a FIFO,
        # device or '-' is written in place (fusion.outputs). Rows are written through the OutputFile, whose
        # write() turns an OSError into one line naming the path and drops the cut temporary file.
        self._out: OutputFile | None = OutputFile(self.path, "w", what="estimates", line_buffered=True)
        self._csv = csv.writer(self._out, lineterminator="\n") if self.format == "csv" else None
        if layout is not None:
            self._start(layout.names)

    def _start(self, names: tuple[str, ...] | list[str]) -> None:
        self._names = list(names)
        self._columns = ["t", *self._names, *(f"sd_{n}" for n in self._names), "reason", "sensor"]
        if self._csv is not None:
            self._csv.writerow(self._columns)
            self._flush()

    def _flush(self) -> None:
        # line buffering flushes on newline already; stdout may be block-buffered when piped
        if not self._owns and self._out is not None:
            self._out.flush()

    @property
    def writing(self) -> str:
        """The file being written now: the temporary name until ``close()``, or the path of a stream."""
        return (self._out.temporary if self._out is not None else None) or self.path

    @property
    def columns(self) -> list[str] | None:
        """The column names (None until the layout is known)."""
        return self._columns

    def on_estimate(self, estimate: Estimate) -> None:
        if self._out is None:
            raise ValueError(f"estimate writer {self.path} is closed")
        b = estimate.belief
        x = b.x.tolist()
        if self._columns is None:  # no layout given: name the elements x0, x1, ..
            self._start([f"x{i}" for i in range(len(x))])
        if len(x) != len(self._names):
            raise ValueError(f"estimate has {len(x)} elements, the output columns name {len(self._names)}")
        sd = b.sd.tolist()
        sensor = estimate.sensor or ""
        if self._csv is not None:
            self._csv.writerow([estimate.t, *x, *sd, estimate.reason, sensor])
        else:
            vals = [estimate.t, *x, *sd]
            obj = {k: (v if math.isfinite(v) else None) for k, v in zip(self._columns, vals)}
            obj["reason"], obj["sensor"] = estimate.reason, estimate.sensor
            self._out.write(json.dumps(obj) + "\n")
        self.rows += 1
        self._flush()

    def close(self) -> None:
        out, self._out = self._out, None
        if out is not None:
            out.close()

    def discard(self) -> None:
        """Close without keeping the file: its temporary file is removed, nothing appears under the final
        name (a stream keeps what it got)."""
        out, self._out = self._out, None
        if out is not None:
            out.discard()

    def __enter__(self) -> "EstimateWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
