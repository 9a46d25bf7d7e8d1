"""SIGTERM and SIGHUP (``timeout``, ``kill``, systemd, ``docker stop``, a closed terminal) stop ``fusion run``
as Ctrl-C does: what was read is processed and summarised, the outputs are completed under their names (no
hidden ``.NAME.XXXX.tmp`` left), ``--summary-json`` is written, and the exit status is 128 + the signal
(143, 129). ``fusion.cli.stop_signals`` is installed only in the main thread and restored after."""
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from fusion.cli import STOP_SIGNALS, Stopped, main, stop_signals
from fusion.outputs import OutputFile

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"
RECORDING = ROOT / "recordings" / "example_2d.log"

pytestmark = pytest.mark.skipif(not hasattr(signal, "SIGHUP"), reason="POSIX signals")


def _rows(path: Path) -> int:
    try:
        return max(0, path.read_text().count("\n") - 1)
    except OSError:
        return 0


@pytest.mark.parametrize("sig, status", [(signal.SIGTERM, 143), (signal.SIGHUP, 129)])
def test_a_signal_stops_fusion_run_as_ctrl_c_does(tmp_path, sig, status):
    """The run reads a pipe that stays open (a live stream): the signal arrives while it waits for more."""
    lines = RECORDING.read_text().splitlines(True)
    head = "".join(lines[: len(lines) // 2])
    out, summary = tmp_path / "est.csv", tmp_path / "s.json"
    cmd = [sys.executable, "-m", "fusion.cli", "run", str(CONFIG), "--input", "-", "-o", str(out),
           "--summary-json", str(summary), "-q", "--no-progress"]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=tmp_path)
    try:
        proc.stdin.write(head)
        proc.stdin.flush()
        t0 = time.monotonic()   # estimates are written as they go: wait until some are on disk
        while not any(_rows(p) > 10 for p in tmp_path.glob(".est.csv.*.tmp")) and proc.poll() is None:
            assert time.monotonic() - t0 < 20, "no estimates written"
            time.sleep(0.05)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == status, err
    assert "interrupted; the summary covers what was read" in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["est.csv", "s.json"]   # no temporary file left
    s = json.loads(summary.read_text())
    assert s["interrupted"] is True and s["sensors"]["uwb"]["received"] > 0
    assert _rows(out) > 10 and out.read_text().endswith("\n")   # completed: every row whole


def test_a_signal_discards_an_output_being_written(tmp_path):
    """What ``fusion simulate`` and ``fusion sweep`` rely on: an OutputFile block that a signal interrupts
    leaves no temporary file (Stopped is a KeyboardInterrupt: the block is discarded, as on Ctrl-C)."""
    target = tmp_path / "out.log"
    with stop_signals() as received:
        with pytest.raises(Stopped) as info:
            with OutputFile(target) as fh:
                fh.write("0.0,uwb,B1,1.0\n")
                assert Path(fh.temporary).exists()
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(5)   # the handler raises before this ends
    assert info.value.signum == signal.SIGTERM and received == [signal.SIGTERM]
    assert list(tmp_path.iterdir()) == []


def test_handlers_are_restored_and_only_set_in_the_main_thread():
    before = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    with stop_signals():
        assert all(signal.getsignal(s) is not before[s] for s in STOP_SIGNALS)
    assert {s: signal.getsignal(s) for s in STOP_SIGNALS} == before
    seen = []

    def other():
        with stop_signals() as received:
            seen.append(({s: signal.getsignal(s) for s in STOP_SIGNALS}, received))

    t = threading.Thread(target=other)
    t.start()
    t.join()
    assert seen == [(before, [])]


def test_fusion_simulate_stopped_by_sigterm_leaves_no_temporary_file(tmp_path, monkeypatch, capsys):
    """A signal while the recording is written: exit 143, one line, no file under any name."""
    import fusion.outputs

    real = fusion.outputs.OutputFile.write

    def write_then_signal(self, data):
        real(self, data)
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)

    monkeypatch.setattr(fusion.outputs.OutputFile, "write", write_then_signal)
    out = tmp_path / "sim.log"
    assert main(["simulate", str(ROOT / "scenarios" / "example_2d.yaml"), "-o", str(out)]) == 143
    assert capsys.readouterr().err.strip() == "fusion simulate: stopped by SIGTERM"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("engine", ["serial", "pool"])
def test_fusion_sweep_stopped_by_sigterm_keeps_its_rows(tmp_path, engine):
    """As Ctrl-C: the rows so far are kept (a resumable results file), exit 143, one line."""
    from fusion.sweep.results import read_rows

    out = tmp_path / "r.csv"
    cmd = [sys.executable, "-m", "fusion.cli", "sweep", str(ROOT / "configs" / "uwb_pv_ukf.yaml"), "--scenario",
           str(ROOT / "scenarios" / "uwb_route1.yaml"), "--seeds", "400", "--param", "scenario.duration=12.0",
           "--engine", engine, "--jobs", "2", "-o", str(out), "--no-progress"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        t0 = time.monotonic()
        while not (out.exists() and out.read_text().count("\n") > 3) and proc.poll() is None:
            assert time.monotonic() - t0 < 60, "no rows"
            time.sleep(0.1)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == "fusion sweep: stopped by SIGTERM" and "Traceback" not in err
    rows = read_rows(out)
    assert 3 <= len(rows) < 400 and all(r["status"] == "ok" for r in rows)
    assert [p.name for p in tmp_path.iterdir()] == ["r.csv"]
