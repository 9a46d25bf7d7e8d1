"""``fusion plugins``: every plugin found, built-in and third-party, by kind."""
from __future__ import annotations

import argparse
import inspect

from fusion.kinds import KINDS


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plugins", help="list plugins by kind",
                       description="List every plugin component found (built-in and from installed packages "
                                   "with entry points in group 'fusion'): kind, name and provider.")
    p.add_argument("--verbose", "-v", action="store_true", help="add each plugin's docstring and parameters")
    p.add_argument("--kind", choices=KINDS, help="only this kind")
    p.set_defaults(func=run)


def describe_params(cls) -> list[tuple[str, str, str, str]]:
    """(name, type, default, description) of a component's Params model."""
    rows = []
    for name, f in cls.Params.model_fields.items():
        ann = getattr(f.annotation, "__name__", None) or str(f.annotation).replace("typing.", "")
        default = "required" if f.is_required() else repr(f.default if f.default_factory is None else f.default_factory())
        rows.append((name, ann, default, f.description or ""))
    return rows


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table
    from rich.text import Text

    from fusion.registry import default_registry

    reg = default_registry(warn=False)   # the broken plugins are listed here, not warned about
    console = Console()
    entries = reg.entries(args.kind)   # resolves the lazy ones: a broken target joins reg.broken
    broken = [p for p in reg.broken if args.kind is None or p.kind in (None, args.kind)]
    if not args.verbose:
        table = Table(title="fusion plugins")
        for col in ("kind", "name", "provider", "summary"):
            table.add_column(col)
        for e in entries:
            doc = inspect.getdoc(e.cls) or ""
            # plugin text is shown as it is, never read as rich markup ("Height [m]", a "[/x]")
            table.add_row(*(Text(v) for v in (e.kind, e.name, e.provider, doc.splitlines()[0] if doc else "")))
        for p in broken:
            table.add_row(Text(p.kind or "(plugin)"), Text(p.name or p.plugin), Text(p.package or p.plugin),
                          Text(f"BROKEN: {p.what}", style="red"))
        console.print(table)
        return _report_broken(broken)
    for e in entries:
        console.rule(f"[bold]{e.kind}[/bold] {escape(e.name)}  [dim]{escape(e.provider)}[/dim]")
        console.print(inspect.getdoc(e.cls) or "(no docstring)", markup=False)
        rows = describe_params(e.cls)
        if rows:
            t = Table(show_header=True, box=None)
            for col in ("parameter", "type", "default", "description"):
                t.add_column(col)
            for r in rows:
                t.add_row(*(Text(v) for v in r))
            console.print(t)
    for p in broken:
        console.rule(f"[bold red]broken[/] {escape(p.kind or 'plugin')} {escape(p.name or p.plugin)}  "
                     f"[dim]{escape(p.package or p.plugin)}[/dim]")
        console.print(p.what, markup=False)
    return _report_broken(broken)


def _report_broken(broken) -> int:
    """One line on stderr for each broken plugin (what, where, package, how to block it); exit code 2 if any."""
    import sys

    for p in broken:
        print(f"fusion plugins: error: {p.message()}", file=sys.stderr)
    return 2 if broken else 0
