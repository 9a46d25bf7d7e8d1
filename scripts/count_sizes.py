"""Functions and methods longer than a limit, for the style rule "no function over ~60 lines" (issue 29).

Usage: ``python scripts/count_sizes.py [ROOT ...] [--over N ...]`` (default roots ``fusion plugins``, default
limits 80 and 60). A function's length is ``end_lineno - lineno + 1`` of its ``def`` (decorators excluded,
its docstring and nested functions included); each nested function is also counted on its own. Prints,
per limit, the count and then ``length  path:line  qualified name``, longest first.
"""
from __future__ import annotations

import argparse
import ast
from pathlib import Path


def functions(path: Path) -> list[tuple[int, str, int, str]]:
    """(length in lines, path, line, qualified name) of every function and method in ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found: list[tuple[int, str, int, str]] = []

    def walk(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = f"{prefix}{child.name}"
                found.append((child.end_lineno - child.lineno + 1, str(path), child.lineno, name))
                walk(child, name + ".")
            elif isinstance(child, ast.ClassDef):
                walk(child, f"{prefix}{child.name}.")
            else:
                walk(child, prefix)

    walk(tree, "")
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("roots", nargs="*", default=["fusion", "plugins"])
    parser.add_argument("--over", type=int, nargs="+", default=[80, 60], help="line limits (default 80 60)")
    args = parser.parse_args(argv)
    found = [f for root in args.roots for p in sorted(Path(root).rglob("*.py")) for f in functions(p)]
    found.sort(key=lambda f: (-f[0], f[1], f[2]))
    for limit in args.over:
        over = [f for f in found if f[0] > limit]
        print(f"functions over {limit} lines: {len(over)}")
        for length, path, line, name in over:
            print(f"  {length:4d}  {path}:{line}  {name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
