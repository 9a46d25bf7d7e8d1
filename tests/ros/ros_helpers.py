"""Helpers of the ROS tests: bags written once per session (bagmaker), ``fusion import`` through the CLI and a
reader of what it wrote, by the project's own log parser (fusion.logformat), apart from the importer's writer."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fusion.api import MalformedMessage
from fusion.cli import main
from fusion.logformat import ParsedStream, iter_messages

ROOT = Path(__file__).resolve().parents[2]


def fusion(*args) -> int:
    return main([str(a) for a in args])


class Recording:
    """A written recording read back: ``meta`` (``# key: value``), ``comments``, per sensor times and rows."""

    def __init__(self, path: Path):
        text = Path(path).read_text(encoding="utf-8")
        self.comments = [line for line in text.splitlines() if line.startswith("#")]
        st = ParsedStream()
        self.t: dict[str, list[float]] = {}
        self.rows: dict[str, list[tuple]] = {}
        for m in iter_messages(text.splitlines(), st):
            assert not isinstance(m, MalformedMessage), f"{path}: malformed line {m.lineno}: {m}"
            self.t.setdefault(m.sensor, []).append(m.t)
            self.rows.setdefault(m.sensor, []).append(m.values)
        self.header = st.header

    def times(self, sensor: str) -> np.ndarray:
        return np.array(self.t.get(sensor, []), float)

    def column(self, sensor: str, name: str) -> np.ndarray:
        return np.array(self.rows[sensor], float)[:, self.header.fields[sensor].index(name)]

    def meta(self, key: str) -> str:
        prefix = f"# {key}: "
        return next(c[len(prefix):] for c in self.comments if c.startswith(prefix))
