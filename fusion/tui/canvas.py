"""A braille canvas drawn as rich Text: 2 x 4 dots a terminal cell, vectorised with numpy.

A terminal cell is about twice as tall as wide, so a braille dot is about square: equal scales on both
axes keep a track's shape. Layers drawn later win a cell's colour; text labels overwrite cells.
"""
from __future__ import annotations

import numpy as np
from rich.text import Text

# Bit of the dot at (row 0..3, column 0..1) of a braille cell (Unicode U+2800 block).
_BITS = np.array([[0x01, 0x08], [0x02, 0x10], [0x04, 0x20], [0x40, 0x80]], dtype=np.uint8)


class BrailleCanvas:
    """``cols`` x ``rows`` cells = ``2 cols`` x ``4 rows`` dots; dot (0, 0) is the top left."""

    def __init__(self, cols: int, rows: int):
        self.cols, self.rows = max(1, cols), max(1, rows)
        self.bits = np.zeros((self.rows, self.cols), dtype=np.uint8)
        self.style = np.zeros((self.rows, self.cols), dtype=np.int16)  # index into self._styles, 0 = none
        self._styles: list[str] = [""]
        self._text: dict[tuple[int, int], tuple[str, int]] = {}

    @property
    def width(self) -> int:
        return 2 * self.cols

    @property
    def height(self) -> int:
        return 4 * self.rows

    def _style_id(self, style: str) -> int:
        if style not in self._styles:
            self._styles.append(style)
        return self._styles.index(style)

    def dots(self, x: np.ndarray, y: np.ndarray, style: str = "") -> None:
        """Set dots at integer dot coordinates (x right, y down); those outside are ignored."""
        x = np.asarray(np.rint(x), dtype=np.int64)
        y = np.asarray(np.rint(y), dtype=np.int64)
        keep = (x >= 0) & (x < self.width) & (y >= 0) & (y < self.height)
        x, y = x[keep], y[keep]
        if not x.size:
            return
        r, c = y // 4, x // 2
        np.bitwise_or.at(self.bits, (r, c), _BITS[y % 4, x % 2])
        self.style[r, c] = self._style_id(style)

    def polyline(self, x: np.ndarray, y: np.ndarray, style: str = "") -> None:
        """Connect consecutive points (dot coordinates) with straight runs of dots."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        if x.size < 2:
            self.dots(x, y, style)
            return
        dx, dy = np.diff(x), np.diff(y)
        n = np.clip(np.ceil(np.maximum(np.abs(dx), np.abs(dy))), 1, 4 * (self.width + self.height)).astype(np.int64)
        seg = np.repeat(np.arange(n.size), n)
        frac = (np.arange(seg.size) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n, n)
        self.dots(np.append(x[seg] + frac * dx[seg], x[-1]), np.append(y[seg] + frac * dy[seg], y[-1]), style)

    def text(self, x: float, y: float, label: str, style: str = "") -> None:
        """Write ``label`` starting at the cell holding dot (x, y)."""
        r, c = int(y) // 4, int(x) // 2
        if not 0 <= r < self.rows:
            return
        sid = self._style_id(style)
        for i, ch in enumerate(label):
            if 0 <= c + i < self.cols:
                self._text[(r, c + i)] = (ch, sid)

    def render(self) -> Text:
        """The canvas as rich Text, one line a row of cells."""
        out = Text()
        for r in range(self.rows):
            line = "".join(chr(0x2800 + int(b)) if b else " " for b in self.bits[r])
            chars = list(line)
            styles = [self._styles[int(s)] for s in self.style[r]]
            for (tr, tc), (ch, sid) in self._text.items():
                if tr == r:
                    chars[tc], styles[tc] = ch, self._styles[sid]
            start = 0
            for c in range(1, self.cols + 1):  # runs of equal style
                if c == self.cols or styles[c] != styles[start]:
                    out.append("".join(chars[start:c]), style=styles[start] or None)
                    start = c
            if r < self.rows - 1:
                out.append("\n")
        return out
