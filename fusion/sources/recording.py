"""Recording replay: the lines of a log file (or stdin), with clear errors for a file that is no log."""
from __future__ import annotations

import io
import re
import sys
from pathlib import Path
from typing import Iterator

from fusion.api import InputError, Params, Source
from fusion.logformat import OVERLONG

_PROBE = 65536
#: Longest line read into memory (characters); a log line is at most a few hundred fields (~10 kB).
MAX_LINE = 1 << 20
_CONTROL = re.compile(rb"[\x00-\x08\x0e-\x1f\x7f]")  # bytes no text line holds (tab, CR, LF, FF, VT are text)


def _binary_share(head: bytes, cut: bool) -> tuple[float, float, int | None]:
    """Share of the bytes of ``head`` (the start of a file) in lines that are binary (NUL or another
    control byte, or not UTF-8), the share of those that are only not UTF-8 (no control byte), and the
    offset of the first byte that is not UTF-8 (None: all decode). ``cut``: head ends mid-file, so its
    last line may be cut (a multi-byte character cut by the probe is not an error)."""
    body = head
    if cut and b"\n" in head:
        body = head[: head.rindex(b"\n") + 1]
    binary = encoding = 0
    first_bad = None
    offset = 0
    for line in body.splitlines(keepends=True):
        control = _CONTROL.search(line) is not None
        try:
            line.decode("utf-8")
            bad_utf8 = False
        except UnicodeDecodeError as exc:
            bad_utf8 = not (cut and offset + len(line) == len(head) and exc.reason == "unexpected end of data")
            if bad_utf8 and first_bad is None:
                first_bad = offset + exc.start
        if control or bad_utf8:
            binary += len(line)
            if not control:
                encoding += len(line)
        offset += len(line)
    total = max(len(body), 1)
    return binary / total, encoding / total, first_bad


def open_lines(path: str | Path) -> Iterator[str]:
    """Lines of a recording. InputError (one clear line) when it is missing, a directory, empty, or when
    most of its start (over half of the bytes of its first 64 KiB) is in binary lines (NUL or control
    bytes, or not UTF-8): then it is no log. Binary junk in fewer lines (a NUL a noisy port sent, a cut
    multi-byte character) only spoils those lines: they read with U+FFFD for the bad bytes and are
    counted as malformed by fusion.logformat."""
    if str(path) == "-":
        yield from bounded_lines(io.TextIOWrapper(sys.stdin.buffer, encoding="utf-8", errors="replace"))
        return
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such recording")
    if p.is_dir():
        raise InputError(f"{p}: is a directory, expected a recording (a text log)")
    with p.open("rb") as fh:
        head = fh.read(_PROBE)
    cut = len(head) == _PROBE
    if not head.strip():
        raise InputError(f"{p}: the recording is empty")
    share, encoding, first_bad = _binary_share(head, cut)
    if share > 0.5:
        n = f"{len(head)} bytes" if not cut else f"{len(head) // 1024} KiB"
        if encoding > 0.5 and first_bad is not None:
            raise InputError(f"{p}: not UTF-8 text: {share:.0%} of its first {n} are in lines that do not decode "
                             f"as UTF-8 (byte 0x{head[first_bad]:02x} at offset {first_bad}); recordings are "
                             "UTF-8 logs 't,sensor,v1,...' (convert with iconv -t UTF-8)")
        bom = " (it starts with a UTF-16 byte-order mark: convert it with iconv -f UTF-16 -t UTF-8)" if head[:2] in (
            b"\xff\xfe", b"\xfe\xff") else ""
        raise InputError(f"{p}: binary data, not a text log: {share:.0%} of its first {n} are in lines with NUL or "
                         f"control bytes or invalid UTF-8{bom}; a log is UTF-8 lines 't,sensor,v1,...' (a few bad "
                         "lines are only counted as malformed)")
    # Lines end where the file's own line ends are: at LF (LF or CRLF files: a CR a noisy port sent mid-line
    # then spoils only its line instead of splitting it in two, the second with a garbled time stamp), or
    # at CR for a file without any LF (a device that ends lines with CR alone).
    newline = "\n" if b"\n" in head else None
    with p.open("r", encoding="utf-8", errors="replace", newline=newline) as fh:
        yield from bounded_lines(fh)


def bounded_lines(fh: io.TextIOBase, limit: int = MAX_LINE) -> Iterator[str]:
    """The lines of a text stream, each read into memory up to ``limit`` characters: a longer one (junk
    without a newline: a port sending zeros for an hour) is skipped to its end and stands as its first
    ``limit`` characters plus fusion.logformat.OVERLONG, so it is one malformed line, never one that
    fills the memory or a cut line that parses as a shorter valid one."""
    readline = fh.readline
    while True:
        line = readline(limit)
        if not line:
            return
        if len(line) == limit and line[-1] != "\n":
            rest = readline(limit)
            if rest == "\n":          # exactly limit characters
                line += rest
            elif rest:               # longer: skip to its end
                while rest and rest[-1] != "\n":
                    rest = readline(limit)
                line = line + OVERLONG + "\n"
            yield line
            continue
        yield line


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
        """``file:///abs/path``, ``file://localhost/abs/path``, ``file://rel/path`` (the scheme in any case),
        ``-`` or a plain path."""
        path = url
        if url[:7].lower() == "file://":
            from urllib.parse import unquote

            path = url[7:]
            if path[:10].lower() == "localhost/":
                path = path[9:]
            path = unquote(path)      # RFC 8089: Path.as_uri() and file managers write %20, UTF-8 as %C3%BC
        return cls(cls.Params(path=path, **options))

    def open(self) -> "RecordingSource":
        """fusion.api.Opens: a missing recording (or a folder) is refused before the run starts, one line, as
        an unopenable port is (it read as 'the input stopped early' with a summary of nothing)."""
        path = self.params.path
        if path != "-":
            p = Path(path)
            try:
                p.stat()
            except FileNotFoundError:
                raise InputError(f"{p}: no such recording") from None
            except (OSError, ValueError) as exc:   # a NUL, a name too long, a symlink loop, no permission
                raise InputError(f"{str(p)[:200]}: cannot open the recording: "
                                 f"{getattr(exc, 'strerror', None) or exc}") from None
            if p.is_dir():
                raise InputError(f"{p}: is a directory, expected a recording (a text log)")
        return self

    def input_paths(self) -> tuple[str, ...]:
        """The recording's path (``file://PATH`` already resolved to PATH); none for standard input."""
        return () if self.params.path == "-" else (self.params.path,)

    def lines(self) -> Iterator[str]:
        return open_lines(self.params.path)
