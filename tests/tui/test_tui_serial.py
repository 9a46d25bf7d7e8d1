"""The serial source over pyserial's loop:// and a pty pair (no hardware), alone and feeding the live view."""
import asyncio
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from fusion.api import InputError
from fusion import pipeline
from fusion.config import load_system
from fusion.registry import default_registry
from fusion.sources.serial import PortLost, SerialSource
from fusion.tui.app import make_app
from fusion.tui.event_log import EventLog
from fusion.tui.state_table import StateTable
from fusion.tui.status_line import StatusLine

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"
RECORDING = ROOT / "recordings" / "example_2d.log"

pty_only = pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a pty pair (POSIX)")


def test_serial_source_is_a_registered_plugin():
    assert default_registry().get("source", "serial") is SerialSource


def test_loop_lines_are_split_decoded_and_recorded_byte_for_byte(tmp_path):
    rec = tmp_path / "raw.log"
    src = SerialSource(port="loop://", record=str(rec), timeout=0.05).open()
    sent = [b"1.0,uwb,B1,3.0\r\n", b"# fields uwb beacon range\r\n2.0,uwb,B\xff", b"2,4.5\n3.0,uwb,B3,", b"5.0\n"]
    lines = src.lines()
    src.on_idle = lambda: src.port.write(sent[0]) if not src.bytes_received else None  # a device that starts late
    got = []
    for chunk in sent:
        if chunk is not sent[0]:
            src.port.write(chunk)
        while len(got) < sum(c.count(b"\n") for c in sent[: sent.index(chunk) + 1]):
            got.append(next(lines))
    assert got == ["1.0,uwb,B1,3.0\r\n", "# fields uwb beacon range\r\n", "2.0,uwb,B\ufffd2,4.5\n", "3.0,uwb,B3,5.0\n"]
    rest = []
    reader = threading.Thread(target=lambda: rest.extend(lines))
    reader.start()
    src.port.write(b"4.0,uwb,B4")  # a partial line when the reader is closed
    time.sleep(0.3)
    src.close()
    reader.join(2.0)
    assert rest == ["4.0,uwb,B4"]
    assert src.port is None
    assert rec.read_bytes() == b"".join(sent) + b"4.0,uwb,B4"  # the bad byte too: nothing is lost


def test_first_line_of_a_port_opened_mid_stream_is_not_fused():
    src = SerialSource(port="loop://").open()
    src.port.write(b"560000,uwb,B1,3.0\n1.0,uwb,B2,4.0\n")  # "1234.560000,uwb,..." cut by the open
    lines = src.lines()
    first, second = next(lines), next(lines)
    assert first == "# fusion: first line cut by opening the port mid-stream: 560000,uwb,B1,3.0\n"
    assert second == "1.0,uwb,B2,4.0\n"
    src.close()


def test_close_wakes_a_reader_waiting_on_a_silent_port():
    src = SerialSource(port="loop://", timeout=0.05).open()
    out = []
    reader = threading.Thread(target=lambda: out.extend(src.lines()))
    reader.start()
    time.sleep(0.1)
    src.close()
    reader.join(60.0)  # a hang guard, not a timing: close() must end the blocked read at all
    assert not reader.is_alive()
    assert out == []


def test_missing_port_is_one_clear_input_error():
    with pytest.raises(InputError, match=r"^cannot open /dev/fusion-no-such-port: No such file or directory"):
        SerialSource(port="/dev/fusion-no-such-port").open()
    with pytest.raises(InputError, match="cannot open nosuch://x"):
        SerialSource(port="nosuch://x").open()


@pty_only
def test_pty_delivers_lines_and_a_closed_master_is_a_lost_port():
    master, slave = os.openpty()
    try:
        src = SerialSource(port=os.ttyname(slave), baud=9600, timeout=0.05).open()
        lines = src.lines()
        src.on_idle = lambda: os.write(master, b"1.0,uwb,B1,3.0\r\n2.0,uwb,B2,4.0\n2.5,uwb") and setattr(src, "on_idle", None)
        assert [next(lines), next(lines)] == ["1.0,uwb,B1,3.0\r\n", "2.0,uwb,B2,4.0\n"]
        time.sleep(0.05)
        os.close(master)
        assert next(lines) == "2.5,uwb"  # what was received before the loss is still delivered
        with pytest.raises(PortLost, match=r"^lost /dev/"):
            next(lines)
        assert src.port is None
    finally:
        os.close(slave)


def _write_slowly(fd, data: bytes, chunk: int = 1024):
    for i in range(0, len(data), chunk):
        os.write(fd, data[i:i + chunk])
        time.sleep(0.002)


@pty_only
def test_live_view_over_a_pty_keeps_the_last_state_when_the_port_is_lost(tmp_path):
    text = "".join(RECORDING.read_text().splitlines(True)[:600])
    n_lines = text.count("\n")
    n_uwb = sum(",uwb," in line for line in text.splitlines())
    ref = pipeline.run(load_system(CONFIG), _write(tmp_path / "part.log", text)).last
    master, slave = os.openpty()
    rec = tmp_path / "rec.log"
    src = SerialSource(port=os.ttyname(slave), record=str(rec))
    app = make_app(CONFIG, src)

    async def drive():
        async with app.run_test(size=(130, 40)) as pilot:
            await until_silent_read(src)  # the device starts sending after the port is open
            writer = threading.Thread(target=_write_slowly, args=(master, text.encode()))
            writer.start()
            deadline = time.monotonic() + 15
            while app.latest is None or app.latest.lines < n_lines:
                assert time.monotonic() < deadline, "lines did not arrive"
                await pilot.pause(0.02)
            writer.join()
            assert app.latest.live and app.latest.state == "running"
            os.close(master)
            while app.latest.state != "lost":
                assert time.monotonic() < deadline, "the lost port was not reported"
                await pilot.pause(0.02)
            await pilot.pause(0.05)
            snap = app.latest
            assert snap.counters["uwb"]["received"] == n_uwb
            # The buffered messages were released at the loss: the last state is the whole stream's.
            np.testing.assert_allclose(snap.estimate.belief.x, ref.belief.x, rtol=0, atol=1e-12)
            status = app.query_one(StatusLine).text
            assert "LOST" in status and "lost /dev/" in status and "live" in status
            assert "lost /dev/" in "\n".join(app.query_one(EventLog).lines_text)
            assert app.query_one(StateTable).cells["px"][0] == f"{ref.belief.x[0]:.4f}"
            await pilot.press("q")

    try:
        asyncio.run(drive())
    finally:
        os.close(slave)
    assert rec.read_text() == text


async def until_silent_read(src):
    waited, idle = [], src.on_idle
    src.on_idle = lambda: (waited.append(1), idle())
    deadline = time.monotonic() + 5
    while not waited:
        assert time.monotonic() < deadline
        await asyncio.sleep(0.02)


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_a_port_that_never_sends_a_newline_gives_one_malformed_line_not_a_full_memory(monkeypatch):
    """A device at the wrong baud rate (or /dev/zero) sends bytes without a newline: after MAX_LINE bytes
    they are one overlong (malformed) line and the rest to the next newline is dropped, so the buffer stays
    bounded; the lines after it come through."""
    from fusion import logformat
    from fusion.sources import serial as serial_source

    monkeypatch.setattr(serial_source, "MAX_LINE", 64)
    src = SerialSource(port="loop://", timeout=0.05).open()
    src.port.write(b"1.0,uwb,B1,3.0\n")                        # the first line (cut by the open: a comment)
    lines = src.lines()
    next(lines)
    src.port.write(b"7" * 500)                                  # 500 bytes, no newline
    junk = next(lines)
    src.port.write(b"7" * 10 + b"\n2.0,uwb,B2,4.0\n")            # the rest of the junk, then a line
    good = next(lines)
    assert junk.endswith(logformat.OVERLONG + "\n") and len(junk) <= 64 + 2
    with pytest.raises(logformat.MalformedMessage, match="longer than"):
        logformat.parse_line(junk)
    assert good == "2.0,uwb,B2,4.0\n"
    src.close()


def test_a_socket_port_is_read_in_chunks_not_a_byte_a_read():
    """pyserial's socket:// says only 0 or 1 for in_waiting: reading that many bytes would take one read a
    byte (three system calls a byte, a 1 kHz IMU more than the view could read). Counted reads,
    not a timing. A peer that closes after its last bytes is a lost port after they are delivered."""
    import socket

    server = socket.create_server(("127.0.0.1", 0))
    lines = [f"{i * 0.025:.3f},uwb,B{i % 4 + 1},{10.0 + 0.001 * i:.6f}\n" for i in range(400)]
    data = "".join(lines).encode()

    def device():
        conn, _ = server.accept()
        time.sleep(0.2)
        conn.sendall(data + b"9.9,uwb,B1")   # the last line cut by the close
        time.sleep(0.3)
        conn.close()

    th = threading.Thread(target=device)
    th.start()
    src = SerialSource(port=f"socket://127.0.0.1:{server.getsockname()[1]}", timeout=0.05).open()
    reads = []
    real = src.port.read
    src.port.read = lambda size=1: reads.append(size) or real(size)
    got = []
    with pytest.raises(PortLost, match="socket disconnected"):
        for line in src.lines():
            got.append(line)
    th.join()
    server.close()
    assert got == lines + ["9.9,uwb,B1"]
    assert len([n for n in reads]) < len(data) / 100   # ~16 kB: a few dozen reads, not 16,000


def test_what_a_socket_device_sends_before_the_port_is_open_is_kept(monkeypatch):
    """pyserial's open() ends by discarding the bytes already received (reset_input_buffer): a socket://
    device that sends as soon as it is connected would lose its first burst or all of it. The open
    is slowed here so that the whole stream is waiting before it ends: every line must still be read."""
    import socket

    from serial.urlhandler import protocol_socket

    real_reconfigure = protocol_socket.Serial._reconfigure_port

    def slow_reconfigure(self, *a, **k):
        time.sleep(0.3)                      # the device's data is in the socket before open() returns
        return real_reconfigure(self, *a, **k)

    monkeypatch.setattr(protocol_socket.Serial, "_reconfigure_port", slow_reconfigure)
    server = socket.create_server(("127.0.0.1", 0))
    lines = [f"{i * 0.025:.3f},uwb,B{i % 4 + 1},{10.0 + 0.001 * i:.6f}\n" for i in range(200)]

    def device():
        conn, _ = server.accept()
        conn.sendall("".join(lines).encode())   # at once, as a bridge pushing its stream does
        time.sleep(0.6)
        conn.close()

    th = threading.Thread(target=device)
    th.start()
    src = SerialSource(port=f"socket://127.0.0.1:{server.getsockname()[1]}", timeout=0.05).open()
    assert "reset_input_buffer" not in vars(src.port)                  # the method is pyserial's again
    got = []
    with pytest.raises(PortLost):
        for line in src.lines():
            got.append(line)
    th.join()
    server.close()
    assert got == lines                       # whole, the first line too (a socket stream starts whole)


@pty_only   # (a system with a pty pair has SIGHUP and SIGTERM: POSIX)
@pytest.mark.parametrize("signame,code", [("SIGTERM", 143), ("SIGHUP", 129), ("SIGINT", 130)])
def test_a_stop_signal_closes_the_view_and_restores_the_terminal(signame, code):
    """kill / timeout / a dropped ssh session while the live view runs: Textual handles none of them, and the
    process would die with the terminal in the alternate screen and mouse tracking on. The view
    closes as by 'q' (the escape sequences that leave the alternate screen are written) and exits 128 + the
    signal. Event-driven: the signal is sent once the view has drawn, whatever the machine's speed."""
    import pty
    import select
    import signal
    import sys

    pid, fd = pty.fork()
    if pid == 0:   # the child: the view over the example's recording in real time (67 s: still running)
        os.environ.update(TERM="xterm-256color", COLUMNS="100", LINES="30")
        os.execv(sys.executable, [sys.executable, "-m", "fusion.cli", "tui", str(CONFIG), "--speed", "1"])
    out = bytearray()

    def read_until(pred, seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end and not pred():
            if select.select([fd], [], [], 0.1)[0]:
                try:
                    out.extend(os.read(fd, 65536))
                except OSError:
                    return

    try:
        read_until(lambda: b"\x1b[?1049h" in out and b"uwb" in out, 60)   # in the alternate screen, drawn
        assert b"\x1b[?1049h" in out, out[-500:]
        os.kill(pid, getattr(signal, signame))
        status = None
        end = time.monotonic() + 30
        while status is None and time.monotonic() < end:
            read_until(lambda: False, 0.2)
            done, st = os.waitpid(pid, os.WNOHANG)
            status = st if done else None
        assert status is not None, "the view did not exit"
        assert os.waitstatus_to_exitcode(status) == code
        assert b"\x1b[?1049l" in out                          # left the alternate screen
    finally:
        try:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        except (ProcessLookupError, ChildProcessError):
            pass
        os.close(fd)
