"""``fusion tui [CONFIG]``: the live view (Textual) of a serial device or of a replayed recording.

    fusion tui --port /dev/ttyS0                       # live, default config configs/abps_ins.yaml
    fusion tui configs/uwb_pv_ukf.yaml --port /dev/ttyUSB0 --baud 115200 --record today.log
    fusion tui configs/uwb_pv_ukf.yaml --speed 4       # the config's recording at 4x real time
    fusion tui configs/example_2d.yaml --input walk.log --speed 0
    fusion tui configs/example_2d.yaml --udp 127.0.0.1:9870   # also stream estimates to PlotJuggler
"""
from __future__ import annotations

import argparse
import math
import sys
from contextlib import contextmanager
from pathlib import Path

from fusion.commands.run import Once
from fusion.errors import ConfigError, FusionError, InputError

DEFAULT_CONFIG = Path("configs") / "abps_ins.yaml"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("tui", help="live view of the state from a serial port or a replayed recording",
                       description="Live view (state with 1-sigma, per-sensor counters, events, horizontal track) "
                                   "of the estimator a config composes, fed by a serial device (--port) or by a "
                                   "recording replayed at --speed x real time (the config's own, or --input). "
                                   "Keys: ? lists them all (q quit, p pause, n step, s plot sensor, f follow, +/- zoom).")
    p.add_argument("config", nargs="?", metavar="CONFIG",
                   help=f"system YAML (default: {DEFAULT_CONFIG} when it exists)")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--port", metavar="PORT", action=Once,
                     help="serial device (/dev/ttyUSB0, COM3) or pyserial URL (socket://host:port, loop://)")
    src.add_argument("--input", "-i", metavar="LOG", action=Once, help="replay this recording instead of the config's own")
    p.add_argument("--baud", type=int, default=115200, help="with --port: bit/s, 8N1 (default 115200)")
    p.add_argument("--record", metavar="PATH", action=Once,
                   help="with --port: write every raw byte received to PATH (a recording; must not exist)")
    p.add_argument("--speed", type=float, default=None,
                   help="replays: x real time by sensor time (default 1; 0 = as fast as possible)")
    p.add_argument("--filter", metavar="NAME", action=Once, help="use this filter instead of the config's (kf, ekf, iekf, ukf, srukf)")
    p.add_argument("--filter-param", metavar="KEY=VALUE", action="append", default=[],
                   help="set a filter parameter (repeatable; VALUE is YAML, e.g. alpha=0.5)")
    p.add_argument("--refresh", type=float, default=15.0, metavar="HZ",
                   help="view refreshes per second (default 15; estimates in between are coalesced)")
    p.add_argument("--udp", metavar="HOST:PORT", action=Once,
                   help="also send every estimate and innovation as one JSON datagram (PlotJuggler's UDP server, "
                        "JSON protocol, timestamp field 'timestamp'; its default port is 9870)")
    p.add_argument("--expect-rate", metavar="SENSOR=HZ", action="append", default=[],
                   help="health: the rate a sensor should have (repeatable; default: learned over its first 5 s)")
    p.add_argument("--limit", metavar="SENSOR=S", action="append", default=[],
                   help="health: longest time without an accepted measurement before DEGRADED "
                        "(repeatable; default max(1 s, 10 / expected rate))")
    p.add_argument("--smooth-lag", type=float, default=None, metavar="SECONDS",
                   help="also draw the fixed-lag smoothed estimate, SECONDS of sensor time behind the live one, "
                        "as a second trace in the track and the state plot (docs/smoothing.md)")
    p.add_argument("--no-reconnect", action="store_true",
                   help="with --port: a lost port ends reading (LOST) instead of being reopened with backoff")
    p.set_defaults(func=run)


def _config_path(config: str | None) -> Path:
    """CONFIG, else the default: in the current folder's configs/ (a checkout), else the one installed
    with the package (fusion_configs), else the source tree's."""
    if config is not None:
        return Path(config)
    import fusion

    if (Path.cwd() / DEFAULT_CONFIG).is_file():
        return Path.cwd() / DEFAULT_CONFIG
    try:
        from importlib.resources import files

        shipped = files("fusion_configs").joinpath(DEFAULT_CONFIG.name)
        if shipped.is_file():
            return Path(str(shipped))
    except (ImportError, TypeError):  # an install without the configs package
        pass
    base = Path(fusion.__file__).resolve().parents[1]
    if (base / DEFAULT_CONFIG).is_file():
        return base / DEFAULT_CONFIG
    raise ConfigError(f"no CONFIG given and the default {DEFAULT_CONFIG} was not found; give a system YAML, "
                      "e.g. fusion tui configs/example_2d.yaml --port /dev/ttyUSB0")


def _per_sensor(values: list[str], option: str, unit: str) -> dict[str, float]:
    """``["uwb=40", "imu=100"]`` -> {"uwb": 40.0, "imu": 100.0}; ConfigError naming the bad item."""
    out = {}
    for item in values:
        name, sep, text = item.partition("=")
        try:
            value = float(text) if sep and name else math.nan
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and value > 0.0):
            raise ConfigError(f"{option} {item}: expected SENSOR={unit} with a positive number, e.g. {option} uwb=40")
        out[name.strip()] = value
    return out


def build_app(args: argparse.Namespace):
    """The app the arguments describe; every usage, config and input error is raised here, before the UI
    takes the terminal."""
    from fusion.commands.run import filter_override, refuse_empty
    from fusion.tui.app import make_app

    refuse_empty(args, "--input", "--port", "--record")   # "$LOG" unset: never the config's own recording
    if args.record and not args.port:
        raise ConfigError("--record tees a live --port to a file; a replayed recording is already on disk")
    if args.port and args.speed is not None:
        raise ConfigError("--speed applies to replays; a live --port runs at the device's pace")
    if args.speed is not None and not (math.isfinite(args.speed) and args.speed >= 0.0):
        raise ConfigError(f"--speed {args.speed}: expected a number >= 0 (0 = as fast as possible)")
    if args.baud <= 0:
        raise ConfigError(f"--baud {args.baud}: expected a positive rate in bit/s, e.g. 115200")
    if not (0.5 <= args.refresh <= 60.0):
        raise ConfigError(f"--refresh {args.refresh}: expected 0.5 to 60 refreshes per second")
    if args.input == "-":
        raise ConfigError("--input -: the live view reads its keys from the terminal, so it cannot replay stdin; "
                          "give a file, a --port (socket://host:port for a network stream), or use fusion run")
    if args.record and Path(args.record).exists():
        raise InputError(f"--record {args.record}: the file exists; choose a new name (nothing is overwritten)")
    if args.no_reconnect and not args.port:
        raise ConfigError("--no-reconnect applies to a live --port")
    lag = getattr(args, "smooth_lag", None)
    if lag is not None and not (math.isfinite(lag) and lag >= 0.0):
        raise ConfigError(f"--smooth-lag {lag}: expected a number of seconds >= 0, e.g. --smooth-lag 2")
    rates = _per_sensor(args.expect_rate, "--expect-rate", "HZ")
    limits = _per_sensor(args.limit, "--limit", "S")
    if args.udp:
        from fusion.tui.udp import parse_address

        parse_address(args.udp)
    config = _config_path(args.config)
    override = filter_override(config, args.filter, args.filter_param)
    source = args.input
    if args.port:
        from fusion.sources.select import open_source

        options = dict(baud=args.baud, record=args.record)
        if not args.no_reconnect:
            options["reconnect"] = True
        source = open_source(args.port, device=True, **options)
    if args.record:   # never a file the run reads (the config; a plugin's port reading a file), nor in no folder
        from fusion.outputs import check_outputs

        check_outputs({"--record": args.record}, [config, *source.input_paths()], force=True)
    speed = 1.0 if args.speed is None else args.speed
    return make_app(config, source, speed=speed, refresh_hz=args.refresh, filter_override=override, udp=args.udp,
                    expected_rates=rates, limits=limits, smooth_lag=lag)


@contextmanager
def _exit_on_stop_signals(app):
    """SIGTERM, SIGHUP and SIGINT (``timeout``, ``kill``, a dropped ssh session) close the view as 'q' does: Textual
    handles neither, and a process they killed would leave the terminal in the alternate screen with mouse
    tracking on. The handler asks the app's event loop to exit (``call_soon_threadsafe`` is
    safe in a signal handler); before the loop runs or after, the signal stops the command as Ctrl-C does.
    Yields the list of the signals received."""
    import asyncio
    import signal
    import threading

    from fusion.cli import STOP_SIGNALS, Stopped

    received: list = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return

    def handler(signum, frame):
        received.append(signal.Signals(signum))
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            raise Stopped(signum) from None
        loop.call_soon_threadsafe(app.exit)

    # SIGINT too: in the raw terminal Ctrl-C is a key (Textual's 'ctrl+q to quit'), so a SIGINT comes from
    # kill -INT, and is an interruption like the others (exit 130)
    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, *STOP_SIGNALS)}
    try:
        yield received
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def terminal_problem(stdin=None, stderr=None) -> str | None:
    """Why the view cannot have the terminal (None when it can). Textual reads keys from standard input and
    draws on standard error, so both must be the terminal, and the process must be in the terminal's
    foreground process group: a background one (``cmd &``, or GNU ``timeout`` without ``--foreground``,
    which moves itself and the command to a group of their own) is stopped by the terminal (SIGTTOU) as soon
    as it sets the terminal's mode, and then never draws nor ends on SIGTERM."""
    import os

    streams = (("standard input", stdin or sys.__stdin__, "the view reads its keys there"),
               ("standard error", stderr or sys.__stderr__, "the view draws there; redirect standard output only"))
    fds = []
    for name, stream, why in streams:
        try:
            fd = stream.fileno()
        except (AttributeError, ValueError, OSError):
            fd = -1
        if fd < 0 or not os.isatty(fd):
            return f"{name} is not a terminal ({why}); for a replay without the view use fusion run"
        fds.append(fd)
    try:
        foreground = os.tcgetpgrp(fds[0])
    except OSError:   # no controlling terminal (a terminal opened by a session that is not its own)
        return None
    if foreground != os.getpgrp():
        return ("this process is not in the terminal's foreground process group (started in the background, or "
                "by timeout without --foreground, which runs the command in a group of its own); use timeout "
                "--foreground, or fusion run for a replay without the view")
    return None


def _release(app, args: argparse.Namespace) -> None:
    """Close what ``build_app`` opened (the port, the --udp socket) when the view will not start; an empty
    record file it created is removed (the name is free again for the next try)."""
    feed = getattr(app, "feed", None)
    if feed is not None:
        feed.stop()
    if args.record and Path(args.record).is_file() and Path(args.record).stat().st_size == 0:
        Path(args.record).unlink()


def run(args: argparse.Namespace) -> int:
    app = build_app(args)
    problem = terminal_problem()
    if problem is not None:
        import signal

        _release(app, args)
        if hasattr(signal, "SIGTTOU"):   # the one line is written even from the background (stty tostop)
            signal.signal(signal.SIGTTOU, signal.SIG_IGN)
        raise InputError(f"the live view needs the terminal: {problem}")
    with _exit_on_stop_signals(app) as received:
        app.run()
    feed = getattr(app, "feed", None)
    if feed is not None:   # the worker finishes the run (sinks closed, fusion_on_run_end called) after 'q'
        feed.done.wait(10.0)
    snap = app.latest
    if received:        # SIGTERM / SIGHUP: the view closed as by 'q' (terminal restored, record complete)
        print(f"fusion tui: stopped by {received[0].name}" + (f"; raw input recorded to {args.record}"
                                                               if args.record else ""), file=sys.stderr)
        return 128 + int(received[0])
    if snap is None:
        return 0
    note = f"fusion tui: {snap.lines} lines from {snap.source}"
    if args.record:
        note += f"; raw input recorded to {args.record}"
    print(note)
    if snap.state == "error":
        print(f"fusion tui: {snap.message}", file=sys.stderr)
        return 1
    result = getattr(feed, "result", None)
    if result is not None and result.plugin_errors:
        from fusion.commands.run import report_plugin_errors

        report_plugin_errors("tui", result, debug=getattr(args, "debug", False))
    if snap.state == "lost":
        raise FusionError(snap.message)
    return 2 if result is not None and result.plugin_errors else 0
