"""Importer ``rosbag``: ROS 1 bags (``.bag``) and ROS 2 bags (``.db3``, ``.mcap`` or a bag folder with its
``metadata.yaml``) through the ``rosbags`` package (pure Python: no ROS install).

Topics become sensors by message type (fusion.importers.rosbag_messages), named after the topic
(``/imu/data`` -> ``imu_data``), or as a mapping file says (``--map``, fusion.importers.rosbag_map): other
types by attribute path, and any topic as ``reference`` (another estimator: robot_localization's own
``/odometry/filtered``) or ``truth`` (motion capture). Frames: REP-103/105 ENU world and FLU body into NED and
FRD (fusion.importers.rosbag_frames), said in the header. Times: the messages' header stamps (not the
receive times), in s from the earliest stamp; the receive-minus-stamp delay of each topic is written to the
header. Static transforms (``/tf_static``, and the ``/tf`` transforms that never change: ROS 1's
static_transform_publisher repeats on /tf) give each sensor's mounting on ``base_link`` (lever arm, rotation).

Bad bags: unreadable, truncated or corrupt (InputError, or with ``--partial`` what reads, noted); a topic of
an unknown type or without messages, stamps at zero (the receive time used instead), stamps going backwards
and all-zero covariances are one counted note each.
"""
from __future__ import annotations

import datetime as dt
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from fusion.api import ConfigError, ImportedLog, Importer, ImportRequest, InputError, Stream
from fusion.importers.common import make_stream

from .rosbag_map import BagMapping, TopicMap, load_bag_mapping, sensor_name
from .rosbag_messages import KINDS, NAVSAT_FIELDS, REFERENCE_FIELDS, attribute, has_zero_cov, state_row
from .rosbag_tf import Transform, from_message, mount

FRAME_NOTE = ("NED world from ROS ENU (REP-103: north = y, east = x, down = -z), body FRD from FLU (y and z "
              "negated), quaternions [w x y z] body FRD to NED; covariances re-expressed the same way")
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
STATE_TYPES = ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseWithCovarianceStamped", "geometry_msgs/msg/PoseStamped")
LATLON = ".9f"


class _Topic:
    """What is gathered of one topic: its sensor, how rows are made, stamps, receive times, rows, counts."""

    def __init__(self, topic: str, msgtype: str, sensor: str, spec: TopicMap | None):
        self.topic, self.msgtype, self.sensor, self.spec = topic, msgtype, sensor, spec
        self.kind = KINDS.get(msgtype)
        self.special = sensor in ("reference", "truth")
        self.t: list[int] = []
        self.recv: list[int] = []
        self.rows: list[np.ndarray] = []
        self.frame = ""
        self.zero_stamp = self.backwards = self.zero_cov = self.dropped = 0
        self.last = -1

    def fields(self) -> tuple[str, ...]:
        if self.special:
            return REFERENCE_FIELDS[:len(self.rows[0])] if self.rows else REFERENCE_FIELDS
        if self.spec is not None and self.spec.fields:
            return tuple(self.spec.fields)
        return NAVSAT_FIELDS if self.msgtype == "sensor_msgs/msg/NavSatFix" else self.kind.fields  # type: ignore[union-attr]

    def add(self, msg: Any, recv: int) -> None:
        header = getattr(msg, "header", None)
        stamp = recv
        if header is not None:
            stamp = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
            self.frame = self.frame or header.frame_id.lstrip("/")
            if stamp == 0:
                self.zero_stamp += 1
                stamp = recv
        row = self._row(msg)
        if row is None:
            self.dropped += 1
            return
        if stamp < self.last:
            self.backwards += 1
        self.last = max(self.last, stamp)
        if self.kind is not None and not self.special and has_zero_cov(row, self.kind):
            self.zero_cov += 1
        self.t.append(stamp)
        self.recv.append(recv)
        self.rows.append(row)

    def _row(self, msg: Any) -> np.ndarray | None:
        if self.special:
            return state_row(self.msgtype, msg)
        if self.spec is not None and self.spec.fields:
            return np.array([attribute(msg, path) * self.spec.scale_of(f) + self.spec.offset_of(f)
                             for f, path in self.spec.fields.items()])
        return self.kind.row(msg)  # type: ignore[union-attr]


class RosbagImporter(Importer):
    """ROS 1 (.bag) and ROS 2 (.db3, .mcap, bag folder) bags through rosbags.

    Topics by message type (Imu, NavSatFix, MagneticField, Range, Odometry, PoseWithCovarianceStamped,
    TwistWithCovarianceStamped) or by --map; ENU/FLU into NED/FRD; header stamps; covariances as fields;
    static tf mountings in the header. See docs/ros.md."""

    name = "rosbag"
    suffixes = (".bag", ".db3", ".mcap")
    sensors = ()            # named after the topics (or the mapping)
    takes_map = True        # --map MAP.yaml (fusion.importers.rosbag_map)
    flight_log = False      # its own origin (the first NavSatFix): no fusion.importers.flight.prepare

    def read(self, path: str, request: ImportRequest) -> ImportedLog:
        mapping = load_bag_mapping(request.mapping)
        log = ImportedLog()
        log.meta["source"] = f"{Path(path).name} (ROS bag{', mapping ' + Path(request.mapping).name if request.mapping else ''})"
        log.meta.update(mapping.meta)
        topics, tfs = _read_bag(path, mapping, request, log.notes)
        streams = [s for s in (_stream(tp, request, log) for tp in topics.values()) if s is not None]
        if not any(len(s) for s in streams) and not tfs:
            return log
        _mounts(streams, topics, tfs, mapping.base_frame, log)
        log.streams = streams
        cut(log, request)
        return log


def _open(path: str):
    """An open rosbags AnyReader (InputError: what and where when the bag cannot be read at all)."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    p = Path(path)
    if p.is_dir() and not (p / "metadata.yaml").exists():
        raise InputError(f"{path}: a folder without metadata.yaml is no ROS 2 bag")
    store = get_typestore(Stores.ROS1_NOETIC if p.suffix == ".bag" else Stores.LATEST)
    reader = AnyReader([p], default_typestore=store)
    try:
        reader.open()
    except (AnyReaderError, Exception) as exc:   # rosbags raises its own errors and, on junk, struct/sqlite ones
        # rosbags reads a bag through its index (ROS 1), summary (MCAP) or database: a cut one cannot be read
        # in part, --partial or not; the format's own tool rebuilds it
        hint = {".bag": "; a cut ROS 1 bag is reindexed by `rosbag reindex`",
                ".mcap": "; a cut MCAP file is rebuilt by the mcap CLI's `mcap recover`",
                ".db3": "; a damaged SQLite bag may be rebuilt by sqlite3's `.recover`"}.get(p.suffix, "")
        raise InputError(f"{path}: not a readable ROS bag ({type(exc).__name__}: {' '.join(str(exc).split())})"
                         f"{hint}") from None
    return reader


def _choose(reader, mapping: BagMapping, request: ImportRequest, notes: list[str]) -> tuple[dict, list]:
    """topic -> _Topic for the connections to read, and the tf connections."""
    by_topic = {m.topic: (name, m) for name, m in mapping.by_name().items()}
    chosen: dict[str, _Topic] = {}
    tf_conns, conns = [], []
    unknown: dict[str, str] = {}
    counts = defaultdict(int)
    for c in reader.connections:
        counts[c.topic] += c.msgcount
    for c in reader.connections:
        if c.topic in mapping.skip:
            continue
        if c.msgtype in TF_TYPES:   # /tf_static, and /tf (ROS 1's static_transform_publisher repeats on /tf)
            tf_conns.append(c)
            continue
        name, spec = by_topic.get(c.topic, (None, None))
        special = name in ("reference", "truth")
        if special and c.msgtype not in STATE_TYPES:
            raise ConfigError(f"{request.mapping}: {name}: topic {c.topic} is {c.msgtype}; a {name} is an Odometry, "
                              "PoseWithCovarianceStamped or PoseStamped topic")
        if not special and c.msgtype not in KINDS and not (spec is not None and spec.fields):
            unknown[c.topic] = c.msgtype
            continue
        name = name or sensor_name(c.topic)
        if not request.wants(name):
            continue
        if c.topic not in chosen:
            chosen[c.topic] = _Topic(c.topic, c.msgtype, name, spec)
        conns.append(c)
    for topic, typ in sorted(unknown.items()):
        notes.append(f"topic {topic} ({typ}): a message type without a default mapping, skipped "
                     f"({counts[topic]} messages); map it with --map (docs/ros.md)")
    for topic in sorted(t for t in mapping.by_name().values() for t in [t.topic] if t not in counts):
        notes.append(f"--map: topic {topic} is not in the bag (it has: {', '.join(sorted(counts))})")
    names = [tp.sensor for tp in chosen.values()]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ConfigError(f"topics map to the same sensor name {twice}: name them apart with --map")
    return chosen, conns + tf_conns


def _read_bag(path: str, mapping: BagMapping, request: ImportRequest,
              notes: list[str]) -> tuple[dict[str, _Topic], dict[str, Transform]]:
    reader = _open(path)
    tfs: dict[str, Transform] = {}
    moving = _Moving()
    try:
        chosen, conns = _choose(reader, mapping, request, notes)
        n = 0
        try:
            for conn, recv, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                if conn.msgtype in TF_TYPES and conn.topic.endswith("tf_static"):
                    tfs.update({tr.child: tr for tr in from_message(msg)})
                elif conn.msgtype in TF_TYPES:
                    moving.add(from_message(msg))
                else:
                    chosen[conn.topic].add(msg, int(recv))
                n += 1
        except Exception as exc:   # a cut chunk, a bad record: rosbags' and the storage's own errors
            what = f"truncated or corrupt after {n} messages ({type(exc).__name__}: {' '.join(str(exc).split())})"
            if not request.allow_partial:
                raise InputError(f"{path}: {what}; --partial imports what reads") from None
            notes.append(f"{what}: imported as far as it reads (--partial)")
    finally:
        reader.close()
    for tp in chosen.values():
        if not tp.t and not tp.dropped:
            notes.append(f"topic {tp.topic} ({tp.msgtype}): no messages")
    return chosen, {**moving.fixed(), **tfs}


class _Moving:
    """The transforms of /tf: those that never change (a ROS 1 static_transform_publisher repeating itself) are
    mounts; the others (odom -> base_link) are motion, not used."""

    def __init__(self):
        self.first: dict[tuple[str, str], Transform] = {}
        self.varies: set[tuple[str, str]] = set()

    def add(self, transforms: list[Transform]) -> None:
        for tr in transforms:
            key = (tr.parent, tr.child)
            was = self.first.setdefault(key, tr)
            if key not in self.varies and not (np.allclose(was.t, tr.t, atol=1e-9) and
                                               np.allclose(was.q, tr.q, atol=1e-9)):
                self.varies.add(key)

    def fixed(self) -> dict[str, Transform]:
        return {tr.child: tr for key, tr in self.first.items() if key not in self.varies}


def _stream(tp: _Topic, request: ImportRequest, log: ImportedLog) -> Stream | None:
    if not tp.t:
        if tp.dropped:
            log.notes.append(f"{tp.sensor}: all {tp.dropped} messages dropped ({tp.kind.why if tp.kind else ''})")
        return None
    t_ns = np.asarray(tp.t, np.int64)
    rows = np.vstack(tp.rows)
    meta = {"topic": f"{tp.topic} ({tp.msgtype})"}
    if tp.frame:
        meta["frame_id"] = tp.frame
    delay = (np.asarray(tp.recv, np.int64) - t_ns) / 1e9
    meta["receive_minus_stamp_s"] = f"median {np.median(delay):.6f} min {delay.min():.6f} max {delay.max():.6f}"
    _notes(tp, log.notes)
    fields = tp.fields()
    if tp.msgtype == "sensor_msgs/msg/NavSatFix" and not tp.special:
        rows = _local(rows, log)
    units = tp.spec.units if tp.spec is not None and tp.spec.units else (tp.kind.units if tp.kind and not tp.special else "")
    if units:
        meta["units"] = units
    if tp.spec is not None and tp.spec.time_offset:
        meta["time_offset_s"] = f"{tp.spec.time_offset:g} (added to the header stamps)"
    return Stream(tp.sensor, fields, t_ns, rows, None, meta)


def _notes(tp: _Topic, notes: list[str]) -> None:
    who = f"{tp.sensor} ({tp.topic})"
    if tp.zero_stamp:
        notes.append(f"{who}: {tp.zero_stamp} messages stamped 0 (a driver that does not stamp): their receive "
                     "times used instead")
    if tp.backwards:
        notes.append(f"{who}: header stamps go backwards {tp.backwards} times: the messages are written in stamp "
                     "order")
    if tp.zero_cov:
        notes.append(f"{who}: {tp.zero_cov} messages with an all-zero covariance (robot_localization adds 1e-6 "
                     "to such a diagonal; the omni models do the same, or give the sensor noise: in the config)")
    if tp.dropped and tp.kind is not None:
        notes.append(f"{who}: {tp.dropped} messages {tp.kind.why}, dropped")


def _local(rows: np.ndarray, log: ImportedLog) -> np.ndarray:
    """NavSatFix rows (lat lon alt c..) as NED positions about the recording's origin (its first fix)."""
    import pymap3d

    if "origin" not in log.meta:
        log.meta["origin"] = f"{rows[0, 0]:{LATLON}} {rows[0, 1]:{LATLON}} {rows[0, 2]:.3f}"
        log.meta["origin_source"] = "the first NavSatFix with a fix (lat lon deg, alt m as the receiver gives it)"
    lat0, lon0, alt0 = (float(v) for v in log.meta["origin"].split())
    n, e, d = pymap3d.geodetic2ned(rows[:, 0], rows[:, 1], rows[:, 2], lat0, lon0, alt0)
    return np.column_stack([n, e, d, rows[:, 3:]])


def _mounts(streams: list[Stream], topics: dict[str, _Topic], tfs: dict[str, Transform], base: str,
            log: ImportedLog) -> None:
    """Time axis (s from the earliest stamp), span cut, start time, frames and mounts into the header."""
    t0 = min((int(s.t.min()) for s in streams if len(s)), default=0)
    log.meta["start_time"] = dt.datetime.fromtimestamp(t0 / 1e9, dt.timezone.utc).isoformat()
    log.meta["time"] = "header stamps, s from start_time (receive times only where a stamp is 0)"
    log.meta["frame"] = FRAME_NOTE
    for tr in tfs.values():
        log.meta[f"tf {tr.parent} {tr.child}"] = tr.as_args() + " (x y z m, roll pitch yaw rad; ROS FLU, static)"
    by_sensor = {tp.sensor: tp for tp in topics.values()}
    for s in streams:
        tp = by_sensor[s.sensor]
        offset = tp.spec.time_offset if tp.spec is not None else 0.0
        t = (np.asarray(s.t, np.int64) - t0) / 1e9 + offset
        m = mount(tfs, base, tp.frame)
        if m is not None:
            arm, q = m
            s.meta["mount"] = (f"lever_arm {' '.join(f'{v:.6g}' for v in arm)} m (body FRD), rotation "
                               f"{' '.join(f'{v:.9g}' for v in q)} (sensor FRD to body FRD, [w x y z]), from "
                               f"the static transforms {base} -> {tp.frame}")
        s.t = t
    log.meta["base_frame"] = base


def cut(log: ImportedLog, request: ImportRequest) -> None:
    """The streams cut to the request's span (s from start_time), non-finite rows dropped with a note."""
    out = []
    for s in log.streams:
        out.append(make_stream(s.sensor, s.fields, s.t, s.values, request, s.formats, s.meta, log.notes))
    log.streams = out
