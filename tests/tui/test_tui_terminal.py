"""``fusion tui`` without the terminal (issue 28 item 3): started in a background process group (GNU
``timeout`` without ``--foreground``) it would be stopped by the terminal (SIGTTOU), and with standard
error redirected it would draw into the file: each is one exit-2 line, at once."""
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fusion.commands.tui import terminal_problem

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"
pty_only = pytest.mark.skipif(not hasattr(os, "openpty") or sys.platform == "win32", reason="needs a pty")
#: A bound far above the ~2 s the command takes to refuse: a stopped or hung view fails the test instead of
#: stopping the suite (not a timing assertion).
BOUND_S = 90


def in_a_terminal(shell: str) -> tuple[int | None, bytes]:
    """Run ``shell`` (bash) as the leader of a new session whose controlling terminal is a pty, as a shell in
    a terminal window runs a command; returns (exit code or None when it did not end, what the pty got)."""
    import pty
    import select
    import signal

    pid, fd = pty.fork()
    if pid == 0:
        os.environ.update(TERM="xterm-256color", COLUMNS="100", LINES="30")
        os.execv("/bin/bash", ["bash", "-c", shell])
    out = bytearray()
    status = None
    end = time.monotonic() + BOUND_S
    try:
        while status is None and time.monotonic() < end:
            if select.select([fd], [], [], 0.1)[0]:
                try:
                    out.extend(os.read(fd, 65536))
                except OSError:
                    pass
            done, st = os.waitpid(pid, os.WNOHANG)
            status = st if done else None
    finally:
        if status is None:
            os.killpg(os.getpgid(pid), signal.SIGKILL)   # the session, the stopped view included
            os.waitpid(pid, 0)
        os.close(fd)
    return (os.waitstatus_to_exitcode(status) if status is not None else None), bytes(out)


def fusion_tui(extra: str = "") -> str:
    return f"{sys.executable} -m fusion.cli tui {CONFIG} --speed 1 {extra}"


@pty_only
@pytest.mark.skipif(shutil.which("timeout") is None or not Path("/bin/bash").exists(), reason="needs GNU timeout")
def test_the_view_in_a_background_process_group_says_so_and_ends(tmp_path):
    err = tmp_path / "err.txt"
    code, out = in_a_terminal(f"timeout 600 {fusion_tui()}; echo rc=$?")   # not stopped until killed
    assert code == 0, out[-400:]
    assert b"rc=2" in out, out[-400:]
    assert b"not in the terminal's foreground process group" in out and b"timeout --foreground" in out
    code, out = in_a_terminal(f"timeout 600 {fusion_tui(f'2>{err}')}; echo rc=$?")
    assert code == 0 and b"rc=2" in out, out[-400:]
    text = err.read_text()
    assert "Traceback" not in text and "NoMatches" not in text and len(text.strip().splitlines()) == 1, text


@pty_only
@pytest.mark.skipif(not Path("/bin/bash").exists(), reason="needs bash")
def test_the_view_with_standard_error_redirected_says_so(tmp_path):
    err = tmp_path / "err.txt"
    code, out = in_a_terminal(f"{fusion_tui(f'2>{err}')}; echo rc=$?")   # the view not drawn into the file
    assert code == 0 and b"rc=2" in out, out[-400:]
    text = err.read_text()
    assert text.startswith("fusion tui: error: the live view needs the terminal: standard error is not a terminal")
    assert "\x1b[" not in text and len(text.strip().splitlines()) == 1, text


def test_no_terminal_is_named():
    r, w = os.pipe()
    try:
        with os.fdopen(r, closefd=False) as rf, os.fdopen(w, "w", closefd=False) as wf:
            assert "standard input is not a terminal" in terminal_problem(rf, wf)
    finally:
        os.close(r)
        os.close(w)


def test_a_record_file_is_not_left_behind_when_the_view_cannot_start(tmp_path, capsys):
    from fusion.cli import main

    rec = tmp_path / "raw.log"
    assert main(["tui", str(CONFIG), "--port", "loop://", "--record", str(rec)]) == 2   # pytest's stdin: no tty
    assert "the live view needs the terminal" in capsys.readouterr().err
    assert not rec.exists()   # the name is free for the next try
