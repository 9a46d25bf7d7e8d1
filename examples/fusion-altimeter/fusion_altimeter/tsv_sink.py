"""A sink as a fusion plugin: the estimated position and its sd as tab-separated values.

``fusion run CONFIG --output track.tsv`` picks it by the suffix: one header line, then ``t`` and, for each
element of the position block ``p``, the value and ``sd_`` of it (m), flushed every row.
"""
from __future__ import annotations

from fusion.api import ConfigError, FusionError, Params, Sink


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
        try:
            self._file = open(self.params.path, "x", encoding="utf-8", buffering=1)
        except OSError as exc:
            raise FusionError(f"cannot write {self.params.path}: {exc.strerror or exc}") from None
        self._file.write("\t".join(["t", *names, *(f"sd_{n}" for n in names)]) + "\n")
        self.rows = 0

    def on_estimate(self, estimate) -> None:
        x = estimate.belief.x[self._sl].tolist()
        sd = estimate.belief.sd[self._sl].tolist()
        self._file.write("\t".join(repr(v) for v in [estimate.t, *x, *sd]) + "\n")
        self.rows += 1

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()
