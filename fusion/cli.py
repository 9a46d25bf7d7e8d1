"""The ``fusion`` command: one subcommand a module in fusion.commands (each has ``register(subparsers)``).

Exit codes: 0 success; 2 bad usage, bad config or bad input (one line naming file, line/field and what
is wrong; no traceback unless ``--debug``), or an installed plugin's observer (a hook, a plugin's sink)
that raised during a run whose outputs were written complete without it (one line naming the plugin:
docs/writing-plugins.md section 5); 1 internal error; 141 (128 + SIGPIPE, what a shell reports for
a tool that a closed pipe ended) when the reader of standard output went away (``fusion run -o - | head``):
no message, no traceback, stdout pointed at the null device so that the exit's flush cannot fail again;
143 / 129 (128 + SIGTERM / SIGHUP) when ``fusion run``, ``simulate``, ``sweep`` or ``import`` was stopped by
that signal (``timeout``, ``kill``, systemd, ``docker stop``, a closed terminal): handled as Ctrl-C is
(``stop_signals``), so what was read is summarised and no temporary file is left.
"""
from __future__ import annotations

import os

# Matrices here are at most ~50 x 16: BLAS threads only add hand-off latency (a threaded small triangular
# solve measured ~8 ms against ~1 us single-threaded). Must be set before numpy is first imported.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import importlib  # noqa: E402
import re  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402
import threading  # noqa: E402
import warnings  # noqa: E402
from contextlib import contextmanager  # noqa: E402
from typing import Iterator  # noqa: E402

from fusion import __version__  # noqa: E402
from fusion.errors import FusionError  # noqa: E402

COMMANDS = ("run", "validate", "plugins", "simulate", "tui", "import_", "import_config", "sweep")  # import_: `fusion import`
# Commands that import numpy and scipy.linalg: numpy's unused submodules are deferred for them (start-up).
NUMERIC_COMMANDS = ("run", "validate", "tui", "simulate", "import", "sweep")
# Commands that write outputs: SIGTERM and SIGHUP stop them as Ctrl-C does (stop_signals). The live view
# (tui) handles them itself (fusion.commands.tui: the app exits as by 'q', the terminal restored).
STOPPABLE_COMMANDS = ("run", "simulate", "sweep", "import")
NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|infinity|nan)$", re.IGNORECASE)
STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))


class Stopped(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised in the main thread where Ctrl-C's KeyboardInterrupt would be: every
    ``except KeyboardInterrupt`` (the run loop keeping what was read, an ``OutputFile`` discarding its
    temporary file) handles it as Ctrl-C. ``signum``: the signal."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


@contextmanager
def stop_signals() -> Iterator[list[int]]:
    """Within the block, SIGTERM and SIGHUP raise ``Stopped`` in the main thread (as Ctrl-C raises
    KeyboardInterrupt); yields the list of the signals received. Installed only in the main thread (a
    signal handler can be set nowhere else) and restored after. A process forked inside the block (a
    sweep's pool worker, which its pool ends with SIGTERM) gets the default action, as it would have."""
    if threading.current_thread() is not threading.main_thread():
        yield []
        return
    received: list[int] = []
    owner = os.getpid()

    def handler(signum, frame):
        if os.getpid() != owner:        # a forked child: die of the signal as before
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        received.append(signum)
        raise Stopped(signum)

    previous = {}
    try:
        for sig in STOP_SIGNALS:
            previous[sig] = signal.signal(sig, handler)
        yield received
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def _stopped_status(received: list[int], status: int) -> int:
    """The exit status of a command that a signal of ``received`` interrupted (130 for Ctrl-C): 128 + the
    signal, as a shell reports a process that signal killed (143 SIGTERM, 129 SIGHUP)."""
    return 128 + received[0] if received and status == 130 else status


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fusion",
        description="Plugin-based sensor fusion: compose an estimator from a YAML config and run it over a "
                    "recording or a live serial stream.",
    )
    parser.add_argument("--version", action="version", version=f"fusion {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks for errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        try:
            mod = importlib.import_module(f"fusion.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"fusion.commands.{name}":
                continue
            raise
        mod.register(sub)
    for subparser in sub.choices.values():
        # a negative number in scientific notation (``--start -1e308``, ``-inf``) is a value, not an option:
        # argparse's own test knows only -1 and -1.5 (tester6 #18)
        subparser._negative_number_matcher = NEGATIVE_NUMBER
        # also after the subcommand (``fusion run C --debug``); SUPPRESS keeps a --debug given before it
        subparser.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                               help="show tracebacks for errors (as 'fusion --debug COMMAND')")
    return parser


def _warning_printer(command: str):
    """``warnings.showwarning`` for a command: fusion's own warnings (a ``CapabilityWarning``: a method one
    edit away from a capability; a ``PluginWarning``: a broken installed plugin left out) as one line
    ``fusion COMMAND: warning: ...``, each once, without the Python source line; any other warning as
    Python shows it."""
    shown: set[str] = set()
    default = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        from fusion.api import CapabilityWarning
        from fusion.registry import PluginWarning

        if not issubclass(category, (CapabilityWarning, PluginWarning)):
            return default(message, category, filename, lineno, file, line)
        text = str(message)
        if text not in shown:
            shown.add(text)
            print(f"fusion {command}: warning: {text}", file=file or sys.stderr)

    return show


def main(argv: list[str] | None = None) -> int:
    try:
        parser = build_parser()   # imports every command's module: Ctrl-C here is an interruption too
        args = parser.parse_args(argv)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        if args.command in NUMERIC_COMMANDS:
            from fusion.lazy_imports import defer_unused_numpy_modules

            defer_unused_numpy_modules()
        with warnings.catch_warnings(), _stoppable(args.command) as received:
            warnings.showwarning = _warning_printer(args.command)
            try:
                return _stopped_status(received, int(args.func(args) or 0))
            except KeyboardInterrupt:
                if received:   # before or after the run's own handling: the command's outputs are discarded
                    name = signal.Signals(received[0]).name
                    _print_quietly(f"fusion {args.command}: stopped by {name}")
                    return 128 + received[0]
                raise
            except OSError:
                if received:   # a closed terminal (SIGHUP): printing the summary fails; the files are written
                    return 128 + received[0]
                raise
    except FusionError as exc:
        if _stdout_closed(exc):
            return _end_stdout_closed()
        if args.debug:
            raise
        print(f"fusion {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:   # stdout's reader went away (| head): end quietly, as other tools do
        return _end_stdout_closed()
    except Exception as exc:  # internal error: a bug, not the user's fault
        if isinstance(exc.__cause__, BrokenPipeError) and _stdout_gone():  # a plugin printing, wrapped by the run loop
            return _end_stdout_closed()
        if args.debug:
            raise
        print(f"fusion {args.command}: internal error: {type(exc).__name__}: {exc} (rerun with --debug for a traceback)",
              file=sys.stderr)
        return 1


def _print_quietly(text: str) -> None:
    """One line on stderr, nothing when stderr is gone (the closed terminal that sent SIGHUP)."""
    try:
        print(text, file=sys.stderr)
    except (OSError, ValueError):
        pass


def _stoppable(command: str):
    """``stop_signals()`` for a command that writes outputs, else a block that changes nothing."""
    from contextlib import nullcontext

    return stop_signals() if command in STOPPABLE_COMMANDS else nullcontext([])


def _stdout_closed(exc: BaseException) -> bool:
    """Whether ``exc`` is fusion.outputs.StdoutClosed (a sink's write to ``-`` whose reader went away)."""
    outputs = sys.modules.get("fusion.outputs")  # loaded by whatever raised it; not imported at start-up
    return outputs is not None and isinstance(exc, outputs.StdoutClosed)


def _stdout_gone() -> bool:
    """Whether stdout is a pipe whose reader has gone (poll reports an error on it): a BrokenPipeError of
    something else (a plugin's socket) stays an internal error."""
    try:
        import select

        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(ev & select.POLLERR for _, ev in poller.poll(0))
    except (OSError, ValueError, AttributeError):
        return False


def _end_stdout_closed() -> int:
    from fusion.outputs import stdout_closed

    return stdout_closed()


if __name__ == "__main__":
    sys.exit(main())
