"""Recording replay: the lines of a log file (or stdin), with clear errors for a file that is no log."""
from __future__ import annotations

import io
import sys
from pathlib import Path
from typing import Iterator

from fusion.api import InputError, Params, Source

_PROBE = 65536


def open_lines(path: str | Path) -> Iterator[str]:
    """Lines of a recording. InputError (one clear line) when it is missing, a directory, empty, binary
    or not UTF-8; a stray bad byte mid-file only spoils its own line (counted as malformed later)."""
    if str(path) == "-":
        yield from io.TextIOWrapper(sys.stdin.buffer, encoding="utf-8", errors="replace")
        return
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such recording")
    if p.is_dir():
        raise InputError(f"{p}: is a directory, expected a recording (a text log)")
    with p.open("rb") as fh:
        head = fh.read(_PROBE)
    if not head.strip():
        raise InputError(f"{p}: the recording is empty")
    if b"\x00" in head:
        raise InputError(f"{p}: binary data, not a text log (expected lines 't,sensor,v1,...')")
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as exc:
        if exc.start < len(head) - 4:  # not just a multi-byte character cut by the probe
            raise InputError(f"{p}: not UTF-8 text (byte 0x{head[exc.start]:02x} at offset {exc.start}); "
                             "recordings are UTF-8 logs 't,sensor,v1,...'") from None
    with p.open("r", encoding="utf-8", errors="replace", newline=None) as fh:
        yield from fh


class RecordingSource(Source):
    """Replays a recorded log file (``-`` for standard input, ``file://PATH`` too) line by line: the
    source of any ``--input`` that no other source claims."""

    name = "recording"
    schemes = ("file",)
    suffixes = (".log", ".txt")

    class Params(Params):
        path: str

    @classmethod
    def from_url(cls, url: str, **options) -> "RecordingSource":
        return cls(cls.Params(path=url[len("file://"):] if url.startswith("file://") else url, **options))

    def lines(self) -> Iterator[str]:
        return open_lines(self.params.path)
