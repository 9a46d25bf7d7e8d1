"""A serial port that is unplugged and plugged back (a pty closed and reopened behind a stable symlink,
as udev's /dev/serial/by-id links are): reading resumes, the gap is marked, the record file is complete."""
import asyncio
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from fusion import pipeline
from fusion.config import load_system
from fusion.sources.serial import SerialSource
from fusion.tui.app import make_app
from fusion.tui.event_log import EventLog
from fusion.tui.status_line import StatusLine

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"
RECORDING = ROOT / "recordings" / "example_2d.log"

pytestmark = pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a pty pair (POSIX)")


class Device:
    """A pty whose slave is reached through ``link``; ``unplug()`` closes it, ``plug()`` makes a new one."""

    def __init__(self, link: Path):
        self.link = link
        self.master = self.slave = None
        self.plug()

    def plug(self):
        self.master, self.slave = os.openpty()
        tmp = self.link.with_suffix(".new")
        os.symlink(os.ttyname(self.slave), tmp)
        os.replace(tmp, self.link)

    def unplug(self):
        os.close(self.master)
        os.close(self.slave)
        self.master = self.slave = None

    def write(self, data: bytes, chunk: int = 1024):
        for i in range(0, len(data), chunk):
            os.write(self.master, data[i:i + chunk])
            time.sleep(0.002)

    def close(self):
        if self.master is not None:
            self.unplug()


def wait(cond, timeout=10.0, what="condition"):
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)


def test_source_reopens_a_replugged_port_with_backoff_and_marks_the_gap(tmp_path):
    dev = Device(tmp_path / "ttyFUSION")
    rec = tmp_path / "rec.log"
    src = SerialSource(port=str(dev.link), record=str(rec), reconnect=True, timeout=0.05, backoff=0.05, backoff_max=0.2)
    status, idle = [], []
    src.on_status = lambda *a: status.append(a)
    src.on_idle = lambda: idle.append(1)
    got = []
    reader = threading.Thread(target=lambda: got.extend(src.open().lines()))
    reader.start()
    try:
        wait(lambda: idle, what="a first silent read")
        dev.write(b"1.0,uwb,B1,3.0\n2.0,uwb,B2")  # the loss cuts the second line
        wait(lambda: len(got) >= 1, what="the first line")
        time.sleep(0.1)
        dev.unplug()
        wait(lambda: len(status) >= 4, what="several reopen attempts")  # the link points at a vanished pty
        assert [s[:2] for s in status[:4]] == [("reconnecting", i) for i in (1, 2, 3, 4)]
        assert "No such file or directory" in status[1][2] or "cannot open" in status[1][2]
        # backoff doubles up to backoff_max: 0.05, 0.1, 0.2, 0.2 s
        assert [s[2].rsplit(" in ", 1)[1] for s in status[:4]] == ["0.05 s", "0.1 s", "0.2 s", "0.2 s"]
        dev.plug()
        wait(lambda: status[-1][0] == "connected", what="the port to come back")
        n = len(idle)
        wait(lambda: len(idle) > n, what="a silent read after the return")
        dev.write(b"3.0,uwb,B3,5.0\n")
        wait(lambda: len(got) >= 5, what="data after the return")
    finally:
        src.close()
        reader.join(3.0)
        dev.close()
    assert not reader.is_alive()
    assert got[0] == "1.0,uwb,B1,3.0\n" and got[1] == "2.0,uwb,B2"
    assert got[2].startswith("# fusion: port lost at ") and got[2].endswith("; reconnecting\n")
    assert got[3].startswith("# fusion: port back at ") and f"after {status[-1][1]} attempts" in got[3]
    assert got[4] == "3.0,uwb,B3,5.0\n"
    # The record file is the stream: the cut line ended, one comment line each side of the gap.
    assert rec.read_text().splitlines() == [g.rstrip("\n") for g in got]
    assert src.reconnects == 1


def test_live_view_shows_reconnecting_and_resumes_with_the_record_complete(tmp_path):
    lines = RECORDING.read_text().splitlines(True)[:900]
    first, second = "".join(lines[:450]), "".join(lines[450:])
    text = first + second
    n_uwb = sum(",uwb," in line for line in lines)
    kept = pipeline.Collect()
    pipeline.run(load_system(CONFIG), [*lines], [kept])
    by_t = {e.t: e for e in kept.estimates}
    dev = Device(tmp_path / "ttyFUSION")
    rec = tmp_path / "rec.log"
    src = SerialSource(port=str(dev.link), record=str(rec), reconnect=True, backoff=0.05, backoff_max=0.2)
    app = make_app(CONFIG, src)
    idle = []
    chained = src.on_idle
    src.on_idle = lambda: (idle.append(1), chained())

    async def until(pilot, cond, what, timeout=15.0):
        deadline = time.monotonic() + timeout
        while not cond():
            assert time.monotonic() < deadline, f"timed out waiting for {what}"
            await pilot.pause(0.02)

    async def drive():
        async with app.run_test(size=(120, 40)) as pilot:
            await until(pilot, lambda: idle, "a first silent read")
            await asyncio.to_thread(dev.write, first.encode())
            await until(pilot, lambda: app.latest is not None and app.latest.lines >= 450, "the first half")
            dev.unplug()
            await until(pilot, lambda: app.latest.state == "reconnecting" and app.latest.attempt >= 2, "RECONNECTING")
            status = app.query_one(StatusLine).text
            assert "RECONNECTING (attempt" in status and " LOST " in status
            dev.plug()
            await until(pilot, lambda: app.latest.state == "running", "the port to come back")
            n = len(idle)
            await until(pilot, lambda: len(idle) > n, "a silent read after the return")
            await asyncio.to_thread(dev.write, second.encode())
            await until(pilot, lambda: app.latest.lines >= 900 + 2, "the second half")
            await pilot.pause(0.1)
            snap = app.latest
            assert snap.counters["uwb"]["received"] == n_uwb and snap.counters["uwb"]["malformed"] == 0
            # Fused as `fusion run` fuses the same lines: the gap changed nothing but the comment lines.
            ref = by_t[snap.estimate.t]
            np.testing.assert_array_equal(snap.estimate.belief.x, ref.belief.x)
            log = "\n".join(app.query_one(EventLog).lines_text)
            assert "port lost; reconnecting" in log and "port back after" in log
            assert "RUNNING" in app.query_one(StatusLine).text
            await pilot.press("q")

    try:
        asyncio.run(drive())
    finally:
        dev.close()
    recorded = rec.read_text().splitlines(True)
    marks = [i for i, line in enumerate(recorded) if line.startswith("# fusion: port ")]
    assert marks == [450, 451]  # the gap marked where it happened, on lines of their own
    assert "".join(line for i, line in enumerate(recorded) if i not in marks) == text
