"""Writing the user's outputs without ever destroying their data (DESIGN.md "Outputs").

- ``check_outputs``: before anything is written, an output that is an input of the run (the recording,
  the config, the scenario), that is given twice, or whose folder does not exist, is refused; an
  existing regular file needs ``--force``. All are ``ConfigError`` (exit 2), naming the option.
- ``OutputFile``: a regular file is written under a temporary name beside it and renamed over the target
  when complete (a reader never sees half a file; a symlink is followed, so the link stays and its
  target is replaced); ``-`` is stdout; a FIFO, a character device (a serial port, ``/dev/null``) or a
  socket is written in place as a stream and never replaced. An OSError (disk full, no permission) is a
  ``FusionError`` naming the file: one line, exit 2; the temporary file is removed then, so a failed write
  never leaves a cut file under the final name (nor a hidden ``.NAME.XXXX.tmp``). A replaced file keeps its
  permission bits (a read-only 0444 file stays 0444). Standard output closed by its reader (``| head``) is
  ``StdoutClosed``: the command ends quietly (``stdout_closed``: exit 141, as a tool ended by SIGPIPE).
- ``write_text``: a whole text at once through an ``OutputFile``.
- ``stdout_carries_data``: while a command's output is ``-``, ``sys.stdout`` is stderr (a plugin's
  ``print``, a stray debug line cannot go into the CSV), and ``OutputFile("-")`` keeps the real stdout.

Plugins write their files through ``OutputFile`` too (exported as ``fusion.api.OutputFile``;
docs/writing-plugins.md, "A sink").
"""
from __future__ import annotations

import errno
import os
import stat
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Iterable, Iterator, Mapping

from fusion.errors import ConfigError, FusionError

__all__ = ["check_outputs", "OutputFile", "is_stream", "write_text", "StdoutClosed", "stdout_closed",
           "stdout_carries_data", "data_stdout"]

_data_stdout: IO | None = None   # the real stdout while stdout_carries_data() has sys.stdout on stderr


def data_stdout() -> IO:
    """The standard output data is written to (``-``): the real one, also within ``stdout_carries_data``."""
    return _data_stdout if _data_stdout is not None else sys.stdout


@contextmanager
def stdout_carries_data(carries: bool = True) -> Iterator[None]:
    """Within the block (when ``carries``: an output is ``-``), ``sys.stdout`` is ``sys.stderr``: a plugin's
    ``print()`` (a hook's debug line, a model's) goes to the terminal instead of into the CSV or JSON on
    stdout; ``OutputFile("-")`` writes to the real stdout. Restored
    after the block."""
    global _data_stdout
    if not carries or _data_stdout is not None:
        yield
        return
    real = sys.stdout
    _data_stdout = real
    sys.stdout = sys.stderr
    try:
        yield
    finally:
        sys.stdout = real
        _data_stdout = None

#: Exit status of a command whose standard output was closed by its reader: 128 + SIGPIPE, what a shell
#: reports for a tool that SIGPIPE ended (``seq 1000000 | head -1``), so ``set -o pipefail`` sees it.
EXIT_STDOUT_CLOSED = 141


class StdoutClosed(FusionError):
    """Standard output was closed by its reader (``fusion run -o - | head -3``): not an error of the user's
    input; the CLI ends quietly with ``stdout_closed()``."""


def stdout_closed() -> int:
    """End a command whose standard output was closed by its reader: point file descriptor 1 at the null
    device, so that Python's last flush at exit cannot fail again (the recipe of the Python documentation,
    "Note on SIGPIPE"), and return the exit status, EXIT_STDOUT_CLOSED (141)."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # no real stdout (a test's capture): nothing to flush
        pass
    return EXIT_STDOUT_CLOSED


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


def _file_id(st: os.stat_result) -> tuple[int, int] | None:
    """(device, inode) of a regular file or a FIFO: what an output must never be when an input is it (a
    terminal or other device may well be both the input and an output)."""
    return (st.st_dev, st.st_ino) if stat.S_ISREG(st.st_mode) or stat.S_ISFIFO(st.st_mode) else None


def _open_inputs(inputs: Iterable[str | os.PathLike | None]) -> dict[tuple[int, int], str]:
    """The files the inputs are, by identity: each path's (device, inode), and for ``-`` the file standard
    input has open (``< in.log``), which ``/dev/fd/0``, ``/dev/stdin`` or a link to them name too."""
    ids: dict[tuple[int, int], str] = {}
    for p in inputs:
        if p is None:
            continue
        try:
            if str(p) == "-":
                st, name = os.fstat(sys.stdin.fileno()), "standard input (--input -)"
            else:
                st, name = os.stat(p), str(p)
        except (OSError, ValueError, AttributeError):   # no such file yet, or no real stdin (a test's capture)
            continue
        key = _file_id(st)
        if key is not None:
            ids.setdefault(key, name)
    return ids


def _same_file_as_input(path: str | os.PathLike, ids: Mapping[tuple[int, int], str]) -> str | None:
    """The input that output ``path`` resolves to (through links, ``/dev/fd/N``, a hard link), or None."""
    try:
        key = _file_id(os.stat(path))
    except (OSError, ValueError):
        return None
    return ids.get(key) if key is not None else None


def check_outputs(outputs: Mapping[str, str | os.PathLike | None], inputs: Iterable[str | os.PathLike | None] = (),
                  force: bool = False) -> None:
    """Refuse outputs that would destroy data: ``outputs`` maps an option (``--output``) to its path
    (None: not given); ``inputs`` are the files the run reads (``-``: standard input)."""
    inputs = list(inputs)
    given = {opt: p for opt, p in outputs.items() if p is not None}
    read = {_key(p): str(p) for p in inputs if p is not None and str(p) != "-"}
    open_ids = _open_inputs(inputs)
    seen: dict[str, str] = {}
    stdout: str | None = None
    for opt, path in given.items():
        if str(path) == "-":   # standard output carries one output: two would be mixed (CSV then JSON)
            if stdout is not None:
                raise ConfigError(f"{opt} -: standard output already carries {stdout}; it can hold one output "
                                  f"(give {opt} a file)")
            stdout = opt
            continue
        if _key(path) == os.devnull:  # the null device takes any number
            continue
        key = _key(path)
        same = read.get(key) or _same_file_as_input(path, open_ids)
        if same is not None:
            raise ConfigError(f"{opt} {path}: is an input of this run ({same}); choose another file "
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
    """A text (or binary) output written safely (see the module): ``write(data)``, ``flush()``, then
    ``close()``, and the file appears under its name (a crash before ``close()`` leaves only the temporary
    name; a caller that wants to keep what a crashed run wrote calls ``close()`` then). ``discard()`` drops
    it instead. A failed ``write``, ``flush`` or ``close`` (disk full) discards it and raises FusionError
    naming the file. As a context manager: closed at the end of the block, discarded when the block
    raises."""

    def __init__(self, path: str | os.PathLike, mode: str = "w", what: str = "output", line_buffered: bool = False):
        self.path = os.fspath(path)
        self.what = what
        binary = "b" in mode
        self._tmp: str | None = None
        self._target = self.path
        try:
            if self.path == "-":
                out = data_stdout()
                self.file: IO = out.buffer if binary else out
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
            raise self._failed(exc) from None
        except (AttributeError, ValueError):  # closed (or discarded after a failed write)
            if self.file is None or self.file.closed:
                raise FusionError(f"cannot write {self.what} to {self.path}: it is closed") from None
            raise

    def flush(self) -> None:
        """Flush what is buffered to the file (a stream: to its reader)."""
        f = self.file
        if f is None:
            return
        try:
            f.flush()
        except OSError as exc:
            raise self._failed(exc) from None

    def _failed(self, exc: OSError) -> FusionError:
        """The error of a failed write, after discarding the output (nothing cut is left behind)."""
        self.discard()
        if self.path == "-" and (isinstance(exc, BrokenPipeError) or exc.errno == errno.EPIPE):
            return StdoutClosed(f"{self.what}: standard output was closed by its reader")
        return FusionError(f"cannot write {self.what} to {self.path}: {exc.strerror or exc}")

    def close(self) -> None:
        f = getattr(self, "file", None)
        if f is None:
            return
        try:
            if self._owns:
                f.close()
            else:
                f.flush()
            self.file = None  # type: ignore[assignment]
            if self._tmp is not None:
                os.chmod(self._tmp, _mode_for(self._target))
                os.replace(self._tmp, self._target)
                self._tmp = None
        except OSError as exc:
            raise self._failed(exc) from None

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

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.discard()   # the block failed: what it wrote is not the whole output
        else:
            self.close()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _mode_for(target: str) -> int:
    """Permission bits of the file a new one replaces (so a read-only file stays read-only; the owner
    cannot be kept without privileges), else those of a new file (0666 less the umask)."""
    try:
        return stat.S_IMODE(os.stat(target).st_mode)
    except OSError:
        return 0o666 & ~_umask()


def write_text(path: str | os.PathLike, text: str, what: str = "output") -> None:
    """Write ``text`` to ``path`` safely (see the module)."""
    with OutputFile(path, "w", what=what) as out:
        out.write(text)

