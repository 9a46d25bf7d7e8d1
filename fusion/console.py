"""The ``fusion`` console script's entry: nothing but the standard library before ``fusion.cli`` is
imported, so that Ctrl-C while the command is still importing its modules (the first ~0.1 s) is the same
one line and exit 130 as Ctrl-C later (README: exit codes), not a KeyboardInterrupt traceback and exit 1."""
from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    """Import the command line and run it; 130 when interrupted while importing."""
    try:
        from fusion.cli import main as cli_main
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    return cli_main(argv)
