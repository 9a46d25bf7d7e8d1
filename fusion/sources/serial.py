"""Serial port source (pyserial): lines of the log format from a live device.

The wire format is the recording format (DESIGN.md "Log format"): UTF-8 text, one message a line,
``t,sensor,v1,...[*HH]``, ``\\n`` or ``\\r\\n`` line ends. A bad byte spoils only its own line (decoded with
U+FFFD and then counted as malformed); ``record`` tees the raw bytes, exactly as received, to a file.

``port`` is a device (``/dev/ttyUSB0``, ``COM3``) or any pyserial URL (``loop://``,
``socket://host:port``, ``rfc2217://host:port``), opened with ``serial.serial_for_url``.

Opening a port while the device is sending cuts the first line: when bytes are waiting at the first read
(no silent read timeout before them), the first line, unless a comment, is passed on as a comment (counted
as a line, never fused), since a fragment can still parse with a wrong time. A device that starts
sending after the port is open loses nothing.

Errors: a port that cannot be opened is an ``InputError`` ("cannot open PORT: reason"); a port that fails
while reading (unplugged device, closed pty) is a ``PortLost`` (an ``InputError``) raised from ``lines()``
after the last partial line is yielded, so nothing received is lost.
"""
from __future__ import annotations

import errno
import os
import threading
from typing import BinaryIO, Callable, Iterator

from pydantic import Field

from fusion.api import InputError, Params, Source

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
            self.port = serial.serial_for_url(p.port, baudrate=p.baud, timeout=p.timeout)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise InputError(f"cannot open {p.port}: {_reason(exc)}{_hint(p.port, exc)}") from None
        if p.record:
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
        """Complete lines (with their ``\\n``) as they arrive, until close() or the port fails."""
        with self._lock:
            if self._closed.is_set():
                return
            self._reading = True
        import serial

        buf = bytearray()
        first = True  # the first line is cut when the port is opened while the device is sending
        try:
            port = self.open().port
            while not self._closed.is_set():
                try:
                    chunk = port.read(min(_CHUNK, max(1, port.in_waiting)))
                except (serial.SerialException, OSError) as exc:
                    if self._closed.is_set():
                        break
                    if buf:
                        yield buf.decode("utf-8", "replace")
                        buf.clear()
                    raise PortLost(f"lost {self.params.port}: {_reason(exc)}") from None
                if not chunk:
                    if first and not buf:
                        first = False  # a read timed out before any byte: the device starts on a line
                    if self.on_idle is not None:
                        self.on_idle()
                    continue
                self.bytes_received += len(chunk)
                if self._record is not None:
                    try:
                        self._record.write(chunk)
                        self._record.flush()
                    except OSError as exc:  # stop rather than go on without the record asked for
                        raise InputError(f"cannot write the record file {self.params.record}: {_reason(exc)}") from None
                buf += chunk
                if b"\n" not in chunk:
                    continue
                *done, rest = buf.split(b"\n")
                buf = bytearray(rest)
                for raw in done:
                    text = raw.decode("utf-8", "replace")
                    if first and not text.startswith("#"):
                        # A fragment may still parse ("560000,imu,..." from "1234.560000,imu,...") with a
                        # wrong time that would make every later message late: keep it as a comment (same
                        # line number as in the record file, never fused).
                        first = False
                        text = "# fusion: first line cut by opening the port mid-stream: " + text
                    yield text + "\n"
            if buf:  # closed mid-line: the partial line too
                yield buf.decode("utf-8", "replace")
        finally:
            self._reading = False
            self._shutdown()

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
