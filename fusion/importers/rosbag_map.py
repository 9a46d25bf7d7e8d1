"""The mapping file of a ROS bag (``fusion import BAG --map MAP.yaml``): the CSV mapping's layout with a
``topic`` in place of a ``file`` (docs/ros.md).

.. code-block:: yaml

    sensors:
      wheel: {topic: /wheel/odometry}           # a known type: only its name (default: from the topic)
      baro:                                     # another type: fields by attribute path
        topic: /barometer/height
        fields: {alt: data}                     # field -> attribute ('vector.x', 'ranges.0')
        scale: 1.0                              # value * scale + offset, one number or per field
        units: m
    reference: {topic: /odometry/filtered}      # another estimator's output (never fused)
    truth: {topic: /mocap/odom}                 # ground truth (motion capture)
    skip: [/diagnostics]                        # topics not to import, without a note
    base_frame: base_link                       # the body frame mounts are given in (default base_link)
    meta: {robot: husky}                        # header lines

A topic the file does not name is imported by its type (fusion.importers.rosbag_messages), under the name of
the topic (``/imu/data`` -> ``imu_data``).
"""
from __future__ import annotations

import math
import re

from pydantic import Field, ValidationError, model_validator

from fusion.api import Params
from fusion.logformat import _SENSOR

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class TopicMap(Params):
    """One topic: ``topic``; for a type not mapped by default, ``fields`` (name -> attribute path); ``scale``,
    ``offset`` (value * scale + offset, one number or per field), ``time_offset`` (s added), ``units``."""

    topic: str
    fields: dict[str, str] | None = None
    scale: float | dict[str, float] = 1.0
    offset: float | dict[str, float] = 0.0
    time_offset: float = Field(0.0, ge=-1e10, le=1e10)
    units: str | None = None

    @model_validator(mode="after")
    def _check(self):
        keys = list(self.fields or {})
        bad = [k for k in keys if not _NAME.match(k)]
        if bad:
            raise ValueError(f"field names {bad} are not valid (a letter first, then letters, digits, _)")
        for what in ("scale", "offset"):
            v = getattr(self, what)
            if isinstance(v, dict):
                unknown = sorted(set(v) - set(keys))
                if unknown:
                    raise ValueError(f"{what} names {unknown}, which are not among the fields {keys}")
                if not all(math.isfinite(x) for x in v.values()):
                    raise ValueError(f"{what} must be finite")
        return self

    def scale_of(self, name: str) -> float:
        return self.scale.get(name, 1.0) if isinstance(self.scale, dict) else self.scale

    def offset_of(self, name: str) -> float:
        return self.offset.get(name, 0.0) if isinstance(self.offset, dict) else self.offset


class BagMapping(Params):
    """A bag's mapping file (the module docstring)."""

    sensors: dict[str, TopicMap] = {}
    reference: TopicMap | None = None
    truth: TopicMap | None = None
    skip: list[str] = []
    base_frame: str = "base_link"
    meta: dict[str, str] = {}

    @model_validator(mode="after")
    def _names(self):
        for name in self.sensors:
            if not _SENSOR.match(name) or name in ("truth", "reference"):
                raise ValueError(f"{name!r} is not a usable sensor name (letters, digits, _ . -; truth and "
                                 "reference have keys of their own)")
        topics = [m.topic for m in self.by_name().values()]
        twice = sorted({t for t in topics if topics.count(t) > 1})
        if twice:
            raise ValueError(f"topic(s) {twice} mapped twice")
        return self

    def by_name(self) -> dict[str, TopicMap]:
        """sensor name -> its map, ``reference`` and ``truth`` included."""
        out = dict(self.sensors)
        for special in ("reference", "truth"):
            m = getattr(self, special)
            if m is not None:
                out[special] = m
        return out


def load_bag_mapping(path: str | None) -> BagMapping:
    """The mapping file at ``path`` (ConfigError naming the file, line and field), or an empty mapping."""
    if not path:
        return BagMapping()
    from fusion.yamlsource import load_yaml, pydantic_errors

    doc = load_yaml(path)
    try:
        return BagMapping.model_validate(doc.data or {})
    except ValidationError as exc:
        raise pydantic_errors(doc, exc) from None


def sensor_name(topic: str) -> str:
    """A sensor name for a topic: ``/imu/data`` -> ``imu_data`` (letters, digits and _ kept; a leading digit
    gets ``t``)."""
    name = re.sub(r"[^A-Za-z0-9_]+", "_", topic.strip("/")).strip("_") or "topic"
    return name if re.match(r"[A-Za-z_]", name) else "t" + name
