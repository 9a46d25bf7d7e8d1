"""Splitting a live byte stream into lines the way the recording reader splits a file, so that a device's
``--record`` file replays as the live session read it.

The recording reader (fusion.sources.recording.open_lines) looks at a file's first 64 KiB: with an LF in
it, only LF ends a line (LF and CRLF files; a stray CR a noisy port sent mid-line spoils only its own line);
without one, CR, CRLF and LF all do (a device that ends its lines with CR alone). A live stream cannot
wait for 64 KiB, so ``LineSplitter`` decides as the bytes come: until the first LF, or until 64 KiB have
come without one, CR, CRLF and LF all end a line; from the first LF on, only LF does (a CR before it is
part of the line end, stripped by the parser); after 64 KiB without an LF, CR, CRLF and LF for good. The
two agree on every line except, in a stream that has both kinds, the lines before its first LF.

A line longer than ``limit`` bytes (a device at the wrong baud rate, /dev/zero: no line end) is skipped to
its end and stands as its first ``limit`` bytes plus fusion.logformat.OVERLONG: one malformed line, as
the recording reader's ``bounded_lines`` makes it, never a buffer that fills the memory.
"""
from __future__ import annotations

import re

from fusion.logformat import OVERLONG

__all__ = ["LineSplitter", "PROBE"]

#: Bytes of a stream's start that decide its line ends (the recording reader's probe of a file's head).
PROBE = 65536
_ANY_END = re.compile(rb"\r\n|\r|\n")


class LineSplitter:
    """``feed(bytes)`` -> the complete lines (text, each ending in ``\\n``) the bytes finish; ``end()``
    -> the partial line left (without a line end), or None. Bytes are decoded as UTF-8 with U+FFFD for
    a bad byte (the line is then counted as malformed by the parser)."""

    def __init__(self, limit: int = 1 << 20):
        self.limit = limit
        self.mode: str | None = None   # None: not decided yet; "lf": LF only; "any": CR, CRLF or LF
        self.seen = 0                  # bytes fed before the decision
        self.overlong = 0              # lines cut because they were longer than limit
        self._buf = bytearray()
        self._cr = False               # the last byte was a CR that ended a line: an LF next belongs to it
        self._skipping = False         # inside an overlong line already given: drop bytes to its end

    @property
    def pending(self) -> bool:
        """Bytes of a line not ended yet are held."""
        return bool(self._buf) or self._skipping

    def feed(self, data: bytes) -> list[str]:
        if self._cr and data[:1] == b"\n":   # a CRLF cut between two reads: the stream's first LF, maybe
            data = data[1:]
            if self.mode is None:
                self.mode = "lf"
        self._cr = False
        if not data:
            return []
        if self.mode is None:
            i = data.find(b"\n")
            if i >= 0:   # the stream's first LF: the lines before it end at CR, this one at the LF
                head = data[:i]
                end = b"\r\n" if head[-1:] == b"\r" else b"\n"
                out = self._split(head[:-1] if end == b"\r\n" else head, _ANY_END)
                self._cr = False
                if self._skipping:          # the end of an overlong line already given
                    self._skipping = False
                else:
                    out.append((bytes(self._buf) + end).decode("utf-8", "replace"))
                self._buf.clear()
                self.mode = "lf"
                return out + self._split(data[i + 1:], None)
            self.seen += len(data)
            if self.seen >= PROBE:
                self.mode = "any"
            return self._split(data, _ANY_END)
        return self._split(data, None if self.mode == "lf" else _ANY_END)

    def end(self) -> str | None:
        """The partial line held (the port closed or failed mid-line), and forget it."""
        text = None if self._skipping or not self._buf else self._buf.decode("utf-8", "replace")
        self._buf.clear()
        self._skipping = False
        return text

    def _split(self, data: bytes, ends: re.Pattern | None) -> list[str]:
        if not data:
            return []
        if self._skipping:                   # drop the rest of an overlong line
            m = data.find(b"\n") if ends is None else _first_end(data)
            if m < 0:
                return []
            if ends is not None and data[m:m + 1] == b"\r":
                if m + 1 == len(data):
                    self._cr = True
                elif data[m + 1:m + 2] == b"\n":
                    m += 1
            data = data[m + 1:]
            self._skipping = False
            if not data:
                return []
        buf = self._buf
        if ends is None:
            if b"\n" not in data:
                buf += data
                return self._check_overlong()
            parts = (bytes(buf) + data).split(b"\n") if buf else data.split(b"\n")
        else:
            if b"\n" not in data and b"\r" not in data:
                buf += data
                return self._check_overlong()
            joined = bytes(buf) + data if buf else data
            parts = _ANY_END.split(joined)
            self._cr = joined[-1:] == b"\r"
        buf[:] = parts.pop()
        limit = self.limit
        out = []
        for raw in parts:
            if len(raw) > limit:
                self.overlong += 1
                out.append(raw[:limit].decode("utf-8", "replace") + OVERLONG + "\n")
            else:
                out.append(raw.decode("utf-8", "replace") + "\n")
        return out + self._check_overlong()

    def _check_overlong(self) -> list[str]:
        buf = self._buf
        if len(buf) <= self.limit:
            return []
        self.overlong += 1
        text = bytes(buf[:self.limit]).decode("utf-8", "replace") + OVERLONG + "\n"
        buf.clear()
        self._skipping = True
        return [text]


def _first_end(data: bytes) -> int:
    """Index of the first CR or LF in ``data`` (-1: none)."""
    m = _ANY_END.search(data)
    return -1 if m is None else m.start()
