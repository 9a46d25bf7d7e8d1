"""Throughput of the live view over a pty: at 1,000 lines a second, screen refreshes a second and the CPU
the view's process uses (issue 16 item 8: at least 10 refreshes a second, under half of one core).

    python benchmarks/bench_tui_pty.py [--rate 1000] [--seconds 10] [--config configs/abps_ins.yaml]
    python benchmarks/bench_tui_pty.py --rate 2000 --seconds 10     # headroom
    python benchmarks/bench_tui_pty.py --link socket --rate 0        # socket://, everything at once: lines/s

``--link socket``: the serial line is a TCP connection (``--port socket://127.0.0.1:P``, a ser2net or Wi-Fi
bridge) instead of a pty. ``--rate 0``: the writer sends the whole recording at once, so the lines a
second read are what the view can consume (its throughput). The child also reports the lag the view
shows (``FeedSnapshot.lag_s``, the status line's ``BEHIND by N s``) at the end of the window.

Two pty pairs: the view (``fusion tui CONFIG --port PTY``, Textual's real Linux driver) runs in a child
process whose terminal is the first pty (120 x 40; the parent reads and discards what it draws); the
second pty is the serial line, into which a writer thread in the parent sends the config's recording at
``--rate`` lines a second (in bursts every 10 ms). The child counts the frames Textual writes to the
terminal (``App._display`` calls that reach the driver) and its own CPU time (``time.process_time``, all
threads: UI, feed worker, serial reading) over ``--seconds`` after a 2 s warm-up, and reports them.
The reference measured in the same run: the same lines through ``fusion.pipeline.run`` with no view
(CPU seconds a line), so the view's own cost is the difference.
"""
from __future__ import annotations

import argparse
import fcntl
import json
import os
import struct
import subprocess
import sys
import termios
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def child(config: str, port: str, seconds: float, out: str) -> None:
    """Runs in the view's process: the app, instrumented."""
    from fusion.sources.serial import SerialSource
    from fusion.tui.app import FusionApp, make_app

    frames = [0]
    original = FusionApp._display

    def counted(self, screen, renderable):
        if renderable is not None and not self._batch_count:
            frames[0] += 1
        return original(self, screen, renderable)

    FusionApp._display = counted
    app = make_app(config, SerialSource(port=port, baud=921600))
    marks = {}
    lags = []

    def mark(name):
        marks[name] = (time.monotonic(), time.process_time(), frames[0], app.feed.lines_read, app.updates)
        lags.append(getattr(app.latest, "lag_s", float("nan")))  # (older versions: no lag_s)
        if name == "end":
            app.exit()

    def timers():
        app.set_timer(2.0, lambda: mark("start"))
        app.set_timer(2.0 + seconds, lambda: mark("end"))

    app.call_later(timers)
    app.run()
    (w0, c0, f0, l0, u0), (w1, c1, f1, l1, u1) = marks["start"], marks["end"]
    Path(out).write_text(json.dumps({"wall_s": w1 - w0, "cpu_s": c1 - c0, "frames": f1 - f0, "lines": l1 - l0,
                                     "snapshots": u1 - u0, "state": app.latest.state if app.latest else None,
                                     "lag_s": lags[-1]}))


def reference_cpu_per_line(config: str, lines: list[str]) -> float:
    from fusion import pipeline
    from fusion.config import load_system

    c0 = time.process_time()
    pipeline.run(load_system(config), lines)
    return (time.process_time() - c0) / len(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rate", type=float, default=1000.0, help="lines a second into the serial pty")
    ap.add_argument("--seconds", type=float, default=10.0, help="measured window after a 2 s warm-up")
    ap.add_argument("--link", choices=("pty", "socket"), default="pty",
                    help="the serial line: a pty pair, or a TCP connection (socket://)")
    ap.add_argument("--config", default=str(ROOT / "configs" / "abps_ins.yaml"),
                    help="a config whose recording lasts the warm-up and window at --rate (abps_ins: 30,935 lines)")
    ap.add_argument("--recording", help="the lines to send (default: the config's recording)")
    ap.add_argument("--child", nargs=3, metavar=("PORT", "SECONDS", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        try:
            child(args.config, args.child[0], float(args.child[1]), args.child[2])
        except BaseException:  # the terminal is the discarded pty: leave the reason in a file
            import traceback

            Path(args.child[2] + ".err").write_text(traceback.format_exc())
            raise
        return
    from fusion.config import load_system

    system = load_system(args.config)
    lines = Path(args.recording or system.recording).read_text().splitlines(True)
    term_m, term_s = os.openpty()
    fcntl.ioctl(term_s, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
    if args.link == "pty":
        ser_m, ser_s = os.openpty()
        port = os.ttyname(ser_s)
    else:
        import socket

        server = socket.create_server(("127.0.0.1", 0))
        port = f"socket://127.0.0.1:{server.getsockname()[1]}"
    out = Path(f"/tmp/bench_tui_pty_{os.getpid()}.json")
    env = dict(os.environ, TERM="xterm-256color", COLORTERM="truecolor")
    proc = subprocess.Popen([sys.executable, __file__, "--config", args.config, "--child", port,
                             str(args.seconds), str(out)], stdin=term_s, stdout=term_s, stderr=term_s, env=env,
                            start_new_session=True)
    os.close(term_s)
    if args.link == "socket":
        conn, _ = server.accept()
        send = conn.sendall
    else:
        def send(data):
            os.write(ser_m, data)
    done = threading.Event()

    def drain():  # the terminal: read what the view draws (else it blocks on a full pty)
        while not done.is_set():
            try:
                if not os.read(term_m, 1 << 16):
                    return
            except OSError:
                return

    def write():  # the device: --rate lines a second, in 10 ms bursts, through the recording once
        tick, n = 0.01, max(1, round(args.rate * 0.01)) if args.rate > 0 else len(lines)
        nxt = time.monotonic() + 1.0
        for i in range(0, len(lines), n):
            if done.is_set():
                return
            now = time.monotonic()
            if now < nxt:
                time.sleep(nxt - now)
            try:
                send("".join(lines[i:i + n]).encode())
            except OSError:
                return
            nxt += tick

    threads = [threading.Thread(target=drain, daemon=True), threading.Thread(target=write, daemon=True)]
    for t in threads:
        t.start()
    try:
        proc.wait(timeout=args.seconds + 60)
    finally:
        done.set()
        if proc.poll() is None:
            proc.kill()
    err = Path(str(out) + ".err")
    if err.exists():
        sys.exit("the view failed:\n" + err.read_text())
    stats = json.loads(out.read_text())
    out.unlink()
    ref = reference_cpu_per_line(args.config, lines)
    rate = stats["lines"] / stats["wall_s"]
    print(f"config {Path(args.config).name}, {args.link}, {rate:.0f} lines/s read over {stats['wall_s']:.1f} s "
          f"(asked {args.rate:.0f}{' = all at once' if args.rate <= 0 else ''}; the recording has {len(lines)} "
          f"lines); lag shown at the end {stats['lag_s']:.1f} s")
    print(f"screen refreshes: {stats['frames'] / stats['wall_s']:.1f} /s  (snapshots {stats['snapshots'] / stats['wall_s']:.1f} /s)")
    print(f"view process CPU: {100 * stats['cpu_s'] / stats['wall_s']:.0f}% of one core; "
          f"the same lines through fusion.pipeline.run alone: {100 * ref * rate:.0f}%")


if __name__ == "__main__":
    main()
