"""Helpers of the importer tests: run ``fusion import`` through the CLI, read what it wrote back with the
project's own log parser (fusion.logformat), independently of the importers' writer. (Not a conftest.py:
tests/simulate has one, and two modules named ``conftest`` on sys.path shadow each other.)

The real PX4 log is read from ../shared/logs beside the repository (or the folder FUSION_TEST_LOGS names);
tests that need it skip, naming the missing file, when it is absent."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from fusion.api import MalformedMessage
from fusion.cli import main
from fusion.logformat import ParsedStream, iter_messages

ROOT = Path(__file__).resolve().parents[2]
PX4_LOG = Path(os.environ.get("FUSION_TEST_LOGS", ROOT.parent / "shared" / "logs")) / "px4_sample_log_small.ulg"


def need_px4_log() -> Path:
    if not PX4_LOG.is_file():
        pytest.skip(f"the real PX4 test log is absent: {PX4_LOG} (see ../shared/logs/README.md)")
    return PX4_LOG


def fusion_import(*args: str) -> int:
    return main(["import", *map(str, args)])


class Recording:
    """A written recording read back: ``header`` (fields, meta), ``comments`` (every # line) and per
    sensor the times and rows."""

    def __init__(self, path: Path):
        text = Path(path).read_text(encoding="utf-8")
        self.comments = [line for line in text.splitlines() if line.startswith("#")]
        st = ParsedStream()
        self.t: dict[str, list[float]] = {}
        self.rows: dict[str, list[tuple]] = {}
        self.order: list[float] = []
        for m in iter_messages(text.splitlines(), st):
            assert not isinstance(m, MalformedMessage), f"{path}: malformed line {m.lineno}: {m}"
            self.t.setdefault(m.sensor, []).append(m.t)
            self.rows.setdefault(m.sensor, []).append(m.values)
            self.order.append(m.t)
        self.header = st.header

    def times(self, sensor: str) -> np.ndarray:
        return np.array(self.t.get(sensor, []), float)

    def values(self, sensor: str) -> np.ndarray:
        return np.array(self.rows.get(sensor, []), float)

    def column(self, sensor: str, name: str) -> np.ndarray:
        return self.values(sensor)[:, self.header.fields[sensor].index(name)]


def one_error_line(capsys) -> str:
    """The stderr of a failed command: exactly one line, the CLI's error line."""
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("fusion import: error: "), err
    return err[0]
