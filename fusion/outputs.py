"""Writing the user's outputs without ever destroying their data (DESIGN.md "Outputs").

- ``check_outputs``: before anything is written, an output that is an input of the run (the recording,
  the config, the scenario), that is given twice, or whose folder does not exist, is refused; an
  existing regular file needs ``--force``. All are ``ConfigError`` (exit 2), naming the option.
- ``OutputFile``: a regular file is written under a temporary name beside it and renamed over the target
  when complete (a reader never sees half a file; a symlink is followed, so the link stays and its
  target is replaced); ``-`` is stdout; a FIFO, a character device (a serial port, ``/dev/null``) or a
  socket is written in place as a stream and never replaced. An OSError (disk full, no permission) is a
  ``FusionError`` naming the file: one line, exit 2.
"""
from __future__ import annotations

import os
import stat
import sys
import tempfile
from pathlib import Path
from typing import IO, Iterable, Mapping

from fusion.errors import ConfigError, FusionError

__all__ = ["check_outputs", "OutputFile", "is_stream", "write_text"]


def is_stream(path: str | os.PathLike) -> bool:
    """True for ``-`` and for an existing FIFO, character device or socket (written in place)."""
    if str(path) == "-":
        return True
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return stat.S_ISFIFO(mode) or stat.S_ISCHR(mode) or stat.S_ISSOCK(mode)


def _key(path: str | os.PathLike) -> str:
    return os.path.realpath(os.fspath(path))


def check_outputs(outputs: Mapping[str, str | os.PathLike | None], inputs: Iterable[str | os.PathLike | None] = (),
                  force: bool = False) -> None:
    """Refuse outputs that would destroy data: ``outputs`` maps an option (``--output``) to its path
    (None: not given); ``inputs`` are the files the run reads."""
    given = {opt: p for opt, p in outputs.items() if p is not None}
    read = {_key(p): str(p) for p in inputs if p is not None and str(p) != "-"}
    seen: dict[str, str] = {}
    for opt, path in given.items():
        if str(path) == "-" or _key(path) == os.devnull:  # stdout and the null device take any number
            continue
        key = _key(path)
        if key in read:
            raise ConfigError(f"{opt} {path}: is an input of this run ({read[key]}); choose another file "
                              "(nothing you gave is overwritten)")
        if key in seen:
            raise ConfigError(f"{opt} {path}: the same file as {seen[key]}; give each output its own file")
        seen[key] = opt
        if is_stream(path):
            continue
        p = Path(path)
        if p.is_dir():
            raise ConfigError(f"{opt} {path}: is a folder; give a file name")
        parent = Path(key).parent
        if not parent.is_dir():
            raise ConfigError(f"{opt} {path}: folder {p.parent} does not exist")
        if p.exists() and not force:
            raise ConfigError(f"{opt} {path}: the file exists; choose a new name or pass --force to replace it")


class OutputFile:
    """A text (or binary) output written safely (see the module). Use as a context manager or call
    ``close()``: the file appears under its name once closed (also after an error: what was written is
    kept); ``discard()`` drops it instead."""

    def __init__(self, path: str | os.PathLike, mode: str = "w", what: str = "output", line_buffered: bool = False):
        self.path = os.fspath(path)
        self.what = what
        binary = "b" in mode
        self._tmp: str | None = None
        self._target = self.path
        try:
            if self.path == "-":
                self.file: IO = sys.stdout.buffer if binary else sys.stdout
                self._owns = False
            elif is_stream(self.path):
                self.file = open(self.path, "ab" if binary else "a", **({} if binary else {"encoding": "utf-8"}))
                self._owns = True
            else:
                self._target = _key(self.path)  # through a symlink: replace its target, keep the link
                folder = os.path.dirname(self._target) or "."
                fd, self._tmp = tempfile.mkstemp(prefix=f".{os.path.basename(self._target)}.", suffix=".tmp",
                                                 dir=folder)
                kwargs = {} if binary else {"encoding": "utf-8", "newline": ""}
                if line_buffered and not binary:
                    kwargs["buffering"] = 1
                self.file = os.fdopen(fd, "wb" if binary else "w", **kwargs)
                self._owns = True
        except OSError as exc:
            raise FusionError(f"cannot write {what} to {self.path}: {exc.strerror or exc}") from None

    @property
    def temporary(self) -> str | None:
        """The temporary name being written (None for a stream)."""
        return self._tmp

    def write(self, data) -> None:
        try:
            self.file.write(data)
        except OSError as exc:
            raise FusionError(f"cannot write {self.what} to {self.path}: {exc.strerror or exc}") from None

    def close(self) -> None:
        f = getattr(self, "file", None)
        if f is None:
            return
        self.file = None  # type: ignore[assignment]
        try:
            if self._owns:
                f.close()
            else:
                f.flush()
            if self._tmp is not None:
                mode = 0o666 & ~_umask()
                os.chmod(self._tmp, mode)
                os.replace(self._tmp, self._target)
                self._tmp = None
        except OSError as exc:
            raise FusionError(f"cannot write {self.what} to {self.path}: {exc.strerror or exc}") from None

    def discard(self) -> None:
        f = getattr(self, "file", None)
        self.file = None  # type: ignore[assignment]
        if f is not None and self._owns:
            try:
                f.close()
            except OSError:
                pass
        if self._tmp is not None:
            try:
                os.unlink(self._tmp)
            except OSError:
                pass
            self._tmp = None

    def __enter__(self) -> "OutputFile":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_text(path: str | os.PathLike, text: str, what: str = "output") -> None:
    """Write ``text`` to ``path`` safely (see the module)."""
    with OutputFile(path, "w", what=what) as out:
        out.write(text)

