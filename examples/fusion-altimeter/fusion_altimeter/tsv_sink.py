"""A sink as a fusion plugin: the estimated position and its sd as tab-separated values.

``fusion run CONFIG --output track.tsv`` picks it by the suffix: one header line, then ``t`` and, for each
element of the position block ``p``, the value and ``sd_`` of it (m), flushed every row.

The file is written through ``fusion.api.OutputFile``, as the built-in sinks write theirs (the rules a sink
follows: docs/writing-plugins.md, "A sink"): a regular file under a temporary name beside it, renamed over
PATH by ``close()`` (so ``--force``, checked by ``fusion run`` before the sink is built, replaces a file and
keeps its permission bits, and a reader never sees half a track); ``-``, a FIFO or a device (also through a
link) written in place; a failed write (a full disk) removes the temporary file and is a FusionError naming
the path: one line, exit 2.
"""
from __future__ import annotations

from fusion.api import ConfigError, OutputFile, Params, Sink


class TsvTrack(Sink):
    """Writes ``t`` and the position block ``p`` with its standard deviations as TSV (``.tsv``)."""

    name = "tsv_track"
    suffixes = (".tsv",)

    class Params(Params):
        path: str

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        lay = self.context.layout
        if lay is None or "p" not in lay:
            raise ConfigError("tsv_track needs a state with a position block 'p'")
        self._sl = lay["p"]
        names = lay.block("p").element_names()
        self._out = OutputFile(self.params.path, "w", what="the track", line_buffered=True)
        self._out.write("\t".join(["t", *names, *(f"sd_{n}" for n in names)]) + "\n")
        self.rows = 0

    def on_estimate(self, estimate) -> None:
        x = estimate.belief.x[self._sl].tolist()
        sd = estimate.belief.sd[self._sl].tolist()
        self._out.write("\t".join(repr(v) for v in [estimate.t, *x, *sd]) + "\n")
        self._out.flush()   # every row on its way at once (a FIFO's reader, stdout)
        self.rows += 1

    def close(self) -> None:
        self._out.close()   # renames the temporary file over PATH; a second call does nothing
