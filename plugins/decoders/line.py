"""Decoder ``line``: messages of the fusion log format (DESIGN.md) used as they are framed.

Framing, checksums, ``# fields`` metadata and comments are handled by fusion.logformat when the source
is read; this decoder optionally checks the number of values and that they are numbers.
"""
from __future__ import annotations

from fusion.api import Decoder, MalformedMessage, Message, Params


class LineDecoder(Decoder):
    """The log format's own fields, unchanged (``t,sensor,v1,v2,...``).

    Params: ``count``: expected number of values (None: any); ``numeric``: every value must be a number."""

    name = "line"

    class Params(Params):
        count: int | None = None
        numeric: bool = False

    def decode(self, message: Message) -> Message | None:
        if self.params.count is not None and len(message.values) != self.params.count:
            raise MalformedMessage(f"expected {self.params.count} values, got {len(message.values)}")
        if self.params.numeric and any(isinstance(v, str) for v in message.values):
            raise MalformedMessage(f"expected numbers, got {message.values!r}")
        return message
