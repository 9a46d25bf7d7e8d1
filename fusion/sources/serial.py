"""Serial port source (pyserial): lines of the log format from a live device.

The wire format is the recording format (DESIGN.md "Log format"): UTF-8 text, one message a line,
``t,sensor,v1,...[*HH]``, ``\\n``, ``\\r\\n`` or ``\\r`` line ends, split as the recording reader splits
the record file (fusion.sources.line_splitter), so ``record`` replays as the session read it; a line over
1 MiB is one malformed line (skipped to its end), as in a recording. A bad byte spoils only its own line
(decoded with U+FFFD and then counted as malformed); ``record`` tees the raw bytes, exactly as received,
to a file.

``port`` is a device (``/dev/ttyUSB0``, ``COM3``) or any pyserial URL (``loop://``,
``socket://host:port``, ``rfc2217://host:port``), opened with ``serial.serial_for_url``.

Opening a port while the device is sending cuts the first line: when bytes are waiting at the first read
(no silent read timeout before them), the first line, unless a comment, is passed on as a comment (counted
as a line, never fused), since a fragment can still parse with a wrong time. A device that starts
sending after the port is open loses nothing.

Errors: a port that cannot be opened is an ``InputError`` ("cannot open PORT: reason"); a port that fails
while reading (unplugged device, closed pty) is a ``PortLost`` (an ``InputError``) raised from ``lines()``
after the last partial line is yielded, so nothing received is lost.

Reconnect (``reconnect=True``, what ``fusion tui --port`` uses): a port that fails while reading is closed
and opened again with exponential backoff (``backoff`` s doubling up to ``backoff_max`` s) until it returns
or ``close()`` is called; ``on_status(state, attempt, detail)`` reports ``"reconnecting"`` before each wait
and ``"connected"`` when the port is back. The stream (and the record file, which stays the stream's
byte-exact copy) gets one comment line at the loss and one at the return, so the gap is marked and line
numbers in the record file stay those of the stream:
``# fusion: port lost at 2026-12-01T10:01:02.345Z: Input/output error; reconnecting`` and
``# fusion: port back at ...Z after 3 attempts (4.2 s without data)``. A line cut by the loss is ended
there (a line of its own); the first line after the return is treated as cut by the open (see above).
"""
from __future__ import annotations

import errno
import os
import select
import threading
import time
from datetime import datetime, timezone
from typing import BinaryIO, Callable, Iterator

from pydantic import Field

from fusion.api import InputError, Params, Source
from fusion.logformat import OVERLONG
from fusion.sources.line_splitter import LineSplitter
from fusion.sources.recording import MAX_LINE

_CHUNK = 4096  # bytes per read at most


class PortLost(InputError):
    """The port failed while it was being read (device unplugged, pty closed)."""


def _reason(exc: BaseException) -> str:
    """A short reason from a pyserial/OS error ("No such file or directory", ...)."""
    code = getattr(exc, "errno", None)
    if isinstance(code, int):
        return os.strerror(code)
    text = str(exc)
    return text or type(exc).__name__


def _utc_now() -> str:
    """Wall-clock time for a gap marker: ISO 8601 UTC with milliseconds."""
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _hint(port: str, exc: BaseException) -> str:
    code = getattr(exc, "errno", None)
    if code == errno.EACCES:
        return " (on Linux, add yourself to the 'dialout' group or check the device's permissions)"
    if code == errno.ENOENT:
        try:
            from serial.tools.list_ports import comports

            found = sorted(p.device for p in comports())
        except Exception:  # listing ports is only a hint
            found = []
        return f" (ports found: {', '.join(found)})" if found else " (no serial ports found)"
    return ""


def _read_chunk(port) -> bytes:
    """What has arrived on ``port``, up to _CHUNK bytes, waiting up to the port's timeout for a first byte.
    A device port's ``in_waiting`` counts the bytes waiting; a ``socket://`` port's says only 0 or 1
    ("readable"), so reading ``in_waiting`` bytes would take one byte a read (three system calls a byte: a 1 kHz
    IMU would be more than such a view could read): there the first byte is read as pyserial
    reads it, then what else the socket holds in one ``recv``."""
    waiting = port.in_waiting
    sock = getattr(port, "_socket", None) if waiting <= 1 else None
    if sock is None or not _is_socket_port(port):
        return port.read(min(_CHUNK, max(1, waiting)))
    import serial

    chunk = port.read(1)
    if chunk:
        try:
            if select.select([sock], [], [], 0)[0]:
                more = sock.recv(_CHUNK - 1)
                if not more:
                    raise serial.SerialException("socket disconnected")
                chunk += more
        except BlockingIOError:
            pass
    return chunk


def _open_keeping_input(port):
    """``port.open()`` without the ``reset_input_buffer()`` that pyserial's open ends with: it discards what
    has already arrived, and for a ``socket://`` device that talks first (a TCP bridge, ``ncat -l < log``)
    that is the stream's beginning, often all of it (and the
    ``--record`` file would be empty too). Nothing the device sent is dropped; a partial first line from a tty is
    counted malformed like any other."""
    port.reset_input_buffer = lambda: None   # an instance attribute: shadows the method during open only
    try:
        port.open()
    finally:
        del port.reset_input_buffer
    return port


def _is_socket_port(port) -> bool:
    from serial.urlhandler.protocol_socket import Serial as SocketSerial

    return isinstance(port, SocketSerial)


class SerialSource(Source):
    """Reads lines of the log format from a serial port or pyserial URL (``loop://``, ``socket://``).

    Parameters: ``port`` (device or URL), ``baud`` (bit/s, 8N1), ``timeout`` (s a read waits before the
    reader checks whether it was closed), ``record`` (file that receives every raw byte as received)."""

    name = "serial"
    live = True  # a live stream: paced by the device, not replayed
    devices = True  # character devices: /dev/ttyUSB0, /dev/pts/3, COM3
    schemes = ("loop", "socket", "rfc2217", "spy", "alt", "hwgrep", "cp2110")  # pyserial URL handlers

    class Params(Params):
        port: str
        baud: int = Field(115200, gt=0, description="bit/s (8 data bits, no parity, 1 stop bit)")
        timeout: float = Field(0.1, gt=0.0, description="s a read waits before checking for close()")
        record: str | None = Field(None, description="tee the raw bytes received to this file")
        reconnect: bool = Field(False, description="reopen a port that fails while reading, with backoff")
        backoff: float = Field(0.25, gt=0.0, description="s before the first reopen attempt (doubles each attempt)")
        backoff_max: float = Field(5.0, gt=0.0, description="s between reopen attempts at most")

    def __init__(self, params=None, context=None, **kwargs):
        if params is None and kwargs:
            params = self.Params(**kwargs)
        super().__init__(params, context)
        self.port = None  # the pyserial object once open
        self._record: BinaryIO | None = None
        self._closed = threading.Event()
        self._lock = threading.Lock()
        self._reading = False
        self.bytes_received = 0
        # Called in the reading thread each time a read times out with nothing (a consumer blocked in
        # lines() can refresh its view of a silent port).
        self.on_idle: Callable[[], object] | None = None
        # Called in the reading thread with (state, attempt, detail) while reconnecting: state
        # "reconnecting" (before attempt number ``attempt``) or "connected" (the port is back).
        self.on_status: Callable[[str, int, str], object] | None = None
        self.reconnects = 0  # times the port came back
        self._last_byte = b"\n"  # last byte recorded (a gap marker starts on a line of its own)
        # Bytes -> lines as the recording reader splits the record file (CR, CRLF or LF ends)
        self._splitter = LineSplitter(MAX_LINE)

    @property
    def label(self) -> str:
        """Where the lines come from, for the UI."""
        return f"{self.params.port} @ {self.params.baud} baud"

    def open(self) -> "SerialSource":
        """Open the port (and the record file). InputError, one line, when it cannot be opened."""
        if self.port is not None:
            return self
        import serial

        p = self.params
        try:
            self.port = _open_keeping_input(serial.serial_for_url(p.port, baudrate=p.baud, timeout=p.timeout,
                                                                  do_not_open=True))
        except (serial.SerialException, OSError, ValueError) as exc:
            raise InputError(f"cannot open {p.port}: {_reason(exc)}{_hint(p.port, exc)}") from None
        if p.record and self._record is None:
            try:
                self._record = open(p.record, "xb")  # never overwrite: nothing the user gave is lost
            except OSError as exc:
                self.port.close()
                self.port = None
                raise InputError(f"cannot write the record file {p.record}: {_reason(exc)}") from None
        return self

    def close(self) -> None:
        """Ask the reader to stop (thread-safe); ``lines()`` returns within ``timeout`` seconds."""
        with self._lock:
            self._closed.set()
            reading = self._reading
        if not reading:  # nobody reads: release the port and the record file now
            self._shutdown()
            return
        cancel = getattr(self.port, "cancel_read", None)
        if cancel is not None:
            try:
                cancel()
            except Exception:  # the port may already be gone
                pass

    def lines(self) -> Iterator[str]:
        """Complete lines (with their ``\\n``) as they arrive, until close() or the port fails (with
        ``reconnect``: until close(), the port reopened whenever it fails)."""
        with self._lock:
            if self._closed.is_set():
                return
            self._reading = True
        try:
            self.open()
            while True:
                try:
                    yield from self._read_lines()
                    return
                except PortLost as lost:
                    if not self.params.reconnect or self._closed.is_set():
                        raise
                    lost_at = time.monotonic()
                    reason = str(lost).split(": ", 1)[-1]
                    yield self._mark(f"# fusion: port lost at {_utc_now()}: {reason}; reconnecting\n")
                    attempts = self._reopen()
                    if attempts is None:  # closed while waiting
                        return
                    self.reconnects += 1
                    yield self._mark(f"# fusion: port back at {_utc_now()} after {attempts} attempt"
                                     f"{'s' if attempts > 1 else ''} ({time.monotonic() - lost_at:.1f} s without data)\n")
                    self._status("connected", attempts, "")
        finally:
            self._reading = False
            self._shutdown()

    def _read_lines(self) -> Iterator[str]:
        """Lines from the open port until close(); PortLost when a read fails (after the partial line)."""
        import serial

        split = self._splitter
        port = self.port
        # The first line is cut when a device port is opened while the device is sending; a socket:// stream
        # starts at the connection, so its first line is whole (and is not discarded at open either)
        first = not _is_socket_port(port)
        while not self._closed.is_set():
            try:
                chunk = _read_chunk(port)
            except (serial.SerialException, OSError) as exc:
                if self._closed.is_set():
                    break
                rest = split.end()
                if rest is not None:
                    yield rest
                raise PortLost(f"lost {self.params.port}: {_reason(exc)}") from None
            if not chunk:
                if first and not split.pending:
                    first = False  # a read timed out before any byte: the device starts on a line
                if self.on_idle is not None:
                    self.on_idle()
                continue
            self.bytes_received += len(chunk)
            self._tee(chunk)
            for text in split.feed(chunk):
                if first and not text.startswith("#") and not text.endswith(OVERLONG + "\n"):
                    # A fragment may still parse ("560000,imu,..." from "1234.560000,imu,...") with a
                    # wrong time that would make every later message late: keep it as a comment (same
                    # line number as in the record file, never fused).
                    text = "# fusion: first line cut by opening the port mid-stream: " + text
                first = False
                yield text
        rest = split.end()
        if rest is not None:  # closed mid-line: the partial line too
            yield rest

    def _tee(self, data: bytes) -> None:
        """Append raw bytes to the record file (flushed: a crash loses nothing received)."""
        if self._record is None or not data:
            return
        try:
            self._record.write(data)
            self._record.flush()
        except OSError as exc:  # stop rather than go on without the record asked for
            raise InputError(f"cannot write the record file {self.params.record}: {_reason(exc)}") from None
        self._last_byte = data[-1:]

    def _mark(self, comment: str) -> str:
        """A gap marker: recorded on a line of its own (a line cut by the loss is ended first), ended as the
        stream's lines are (CR for a device that has sent no LF: an LF would change how the record file
        splits, fusion.sources.line_splitter)."""
        eol = b"\r" if self._splitter.mode != "lf" and self.bytes_received else b"\n"
        if self._last_byte not in (b"\n", b"\r"):
            self._tee(eol)
        self._tee(comment.encode("utf-8")[:-1] + eol)
        return comment

    def _status(self, state: str, attempt: int, detail: str) -> None:
        if self.on_status is not None:
            self.on_status(state, attempt, detail)

    def _reopen(self) -> int | None:
        """Close the failed port and open it again with backoff; the number of attempts it took, or None
        when close() was called first."""
        if self.port is not None:
            try:
                self.port.close()
            except Exception:  # a vanished device may fail to close; it is gone anyway
                pass
            self.port = None
        p = self.params
        delay, attempt, why = p.backoff, 0, "port lost"
        while not self._closed.is_set():
            attempt += 1
            self._status("reconnecting", attempt, f"{why}; attempt {attempt} in {delay:.3g} s")
            if self._closed.wait(delay):
                return None
            try:
                self.open()
                return attempt
            except InputError as exc:
                why = str(exc).split(" (", 1)[0]
                delay = min(2.0 * delay, p.backoff_max)
        return None

    def _shutdown(self) -> None:
        if self.port is not None:
            try:
                self.port.close()
            except Exception:  # closing a vanished device may fail; nothing to do
                pass
            self.port = None
        if self._record is not None:
            self._record.close()
            self._record = None
