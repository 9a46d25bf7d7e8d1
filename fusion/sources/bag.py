"""Source ``rosbag``: ``fusion run --input robot.bag`` (``.bag``, ``.db3``, ``.mcap``) replays a ROS bag directly,
without an import step: the bag is read by the ``rosbag`` importer (fusion.importers.rosbag: topics by
message type, ENU/FLU into NED/FRD, header stamps) and its recording's lines are handed to the run as a
recording's would be. ``PATH?map=MAP.yaml`` gives the importer a mapping file (docs/ros.md: reference and
truth topics, other message types). The importer's notes (unknown types, zero stamps) go to stderr."""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Iterator

from fusion.api import InputError, Params, Source


class BagSource(Source):
    """Replays a ROS 1 / ROS 2 bag (.bag, .db3, .mcap; ``PATH?map=MAP.yaml`` for a mapping file) through the
    rosbag importer, as the recording ``fusion import`` would write."""

    name = "rosbag"
    schemes = ("rosbag",)
    suffixes = (".bag", ".db3", ".mcap")

    class Params(Params):
        path: str
        map: str | None = None

    @classmethod
    def from_url(cls, url: str, **options) -> "BagSource":
        """``PATH``, ``PATH?map=MAP.yaml``, or ``rosbag://PATH[?map=MAP.yaml]`` (a ROS 2 bag folder)."""
        if url.lower().startswith("rosbag://"):
            url = url[len("rosbag://"):]
        path, _, query = url.partition("?map=")
        return cls(cls.Params(path=path, map=query or None, **options))

    def input_paths(self) -> tuple[str, ...]:
        return (self.params.path,) + ((self.params.map,) if self.params.map else ())

    def open(self) -> "BagSource":
        p = Path(self.params.path)
        if not p.exists():
            raise InputError(f"{p}: no such bag")
        if self.params.map and not Path(self.params.map).is_file():
            raise InputError(f"{self.params.map}: no such mapping file")
        self._log = self._read()
        return self

    def _read(self):
        """The bag as an ImportedLog (read when the source opens: a bad bag is one line before the run)."""
        from fusion.api import ImportRequest
        from fusion.importers.rosbag import RosbagImporter

        path = self.params.path
        log = RosbagImporter().read(path, ImportRequest(mapping=self.params.map))
        for note in log.notes:
            print(f"{path}: {note}", file=sys.stderr)
        log.streams = [s for s in log.streams if len(s)]
        if not log.streams:
            raise InputError(f"{path}: no messages of a mapped type to replay" + (f" ({'; '.join(log.notes)})" if log.notes else ""))
        return log

    def lines(self) -> Iterator[str]:
        from fusion.importers.writer import render

        log = getattr(self, "_log", None) or self._read()
        yield from render(log)
