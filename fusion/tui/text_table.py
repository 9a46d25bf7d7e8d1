"""Aligned plain-text tables as rich Text: far cheaper to re-render 10-20 times a second than a DataTable
(which renders cell by cell), and all the live tables need."""
from __future__ import annotations

from typing import Sequence

from rich.text import Text


def text_table(headers: Sequence[str], rows: Sequence[Sequence[str]], right: Sequence[bool],
               styles: Sequence[str | None] | None = None) -> Text:
    """Columns as wide as their widest cell, separated by two spaces; ``right`` aligns a column right;
    ``styles`` gives each row a style (None: plain)."""
    widths = [max([len(h)] + [len(r[i]) for r in rows]) for i, h in enumerate(headers)]

    def line(cells: Sequence[str]) -> str:
        return "  ".join(c.rjust(w) if r else c.ljust(w) for c, w, r in zip(cells, widths, right)).rstrip()

    out = Text()
    out.append(line(headers), style="bold")
    for i, row in enumerate(rows):
        out.append("\n")
        out.append(line(row), style=(styles[i] if styles else None) or "")
    return out
