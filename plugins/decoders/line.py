"""Decoder ``line``: messages of the fusion log format (DESIGN.md) used as they are framed.

Framing, checksums, ``# fields`` metadata and comments are handled by fusion.logformat when the source
is read; this decoder optionally checks the number of values and that they are numbers.
"""
from __future__ import annotations

from pydantic import Field

from fusion.api import Decoder, MalformedMessage, Message, Params


class LineDecoder(Decoder):
    """The log format's own fields, unchanged (``t,sensor,v1,v2,...``).

    Params: ``count``: expected number of values (None: any); ``numeric``: every value must be a number
    (else labels pass). A number must be finite. A message that breaks any of these is malformed
    (MalformedMessage with the reason)."""

    name = "line"

    class Params(Params):
        count: int | None = Field(None, ge=0)
        numeric: bool = False

    def decode(self, message: Message) -> Message | None:
        if self.params.count is not None and len(message.values) != self.params.count:
            raise MalformedMessage(f"expected {self.params.count} values, got {len(message.values)}")
        try:  # the common case in one C call: all numbers, all finite (an IMU sample, 100-200 a second)
            total = sum(message.values)
            if total - total == 0.0:
                return message
        except TypeError:  # a label among them
            pass
        numeric = self.params.numeric
        for i, v in enumerate(message.values):
            # fusion.logformat parses only finite numbers and labels; a message from elsewhere may hold a NaN
            if v.__class__ is str:
                if not numeric:
                    continue
            elif isinstance(v, (int, float)) and v - v == 0.0:
                continue
            raise MalformedMessage(f"value {i + 1}: expected a finite number{'' if numeric else ' or a label'}, "
                                   f"got {v!r}")
        return message
