"""Sink ``mcap``: a run as an MCAP file (``--output run.mcap``), for Foxglove and PlotJuggler beside the source bag.

Channels (log time = the estimate's time in ns; the run's time axis, which for a recording ``fusion import``
made of a bag is seconds from its ``start_time``):

- ``/fusion/pose``: ``geometry_msgs/msg/PoseWithCovarianceStamped`` (ROS 2 ``ros2msg`` schema, CDR-encoded by
  rosbags' serializer), in ROS's REP-103 ENU world / FLU body (so it overlays the bag's own topics; the
  project's NED/FRD converted back, fusion.importers.rosbag_frames), covariance of x y z and the rotation
  (roll pitch yaw of an ``omni`` state; the small-angle attitude error of a quaternion state). Only for a
  state with a 3-D position ``p``.
- ``/fusion/estimate``: JSON: ``t``, ``reason``, ``sensor``, ``x`` and ``sd`` by element name (the project's
  frames and units, as the CSV output), and ``P`` the full covariance (row-major).
- ``/fusion/innovation``: JSON of each update: ``sensor``, ``innovation``, ``S``, ``nis``, ``accepted``.
- ``/fusion/events``: the run's events as ``foxglove.Log`` (JSON).

Written through fusion.outputs.OutputFile (a temporary name renamed when the run closes the sink).
"""
from __future__ import annotations

import json
import math

import numpy as np
from pydantic import Field

from fusion.api import BuildContext, Estimate, Event, Params, Sink, StateLayout
from fusion.outputs import OutputFile

ESTIMATE_SCHEMA = {"type": "object", "title": "fusion.Estimate", "properties": {
    "t": {"type": "number", "description": "s"}, "reason": {"type": "string"}, "sensor": {"type": "string"},
    "x": {"type": "object", "description": "state by element name (SI, NED / FRD)"},
    "sd": {"type": "object", "description": "standard deviation by element name"},
    "P": {"type": "array", "items": {"type": "array", "items": {"type": "number"}}}}}
INNOVATION_SCHEMA = {"type": "object", "title": "fusion.Innovation", "properties": {
    "t": {"type": "number"}, "sensor": {"type": "string"}, "innovation": {"type": "array"},
    "S": {"type": "array"}, "nis": {"type": "number"}, "accepted": {"type": "boolean"}}}
LOG_SCHEMA = {"type": "object", "title": "foxglove.Log", "properties": {
    "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}},
    "level": {"type": "integer"}, "message": {"type": "string"}, "name": {"type": "string"},
    "file": {"type": "string"}, "line": {"type": "integer"}}}
POSE_TYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"
LEVELS = {"warning": 3, "not_positive_definite": 4, "malformed": 3, "rejected": 2, "late": 3}   # foxglove.Log


class _Counted:
    """An OutputFile as the binary stream mcap's Writer wants (``write``, ``tell``, ``flush``)."""

    def __init__(self, out: OutputFile):
        self.out, self.n = out, 0

    def write(self, data) -> int:
        self.out.write(data)
        self.n += len(data)
        return len(data)

    def tell(self) -> int:
        return self.n

    def flush(self) -> None:
        self.out.flush()


def _ns(t: float) -> int:
    return max(0, int(round(t * 1e9))) if math.isfinite(t) else 0


def _finite(v):
    return [x if math.isfinite(x) else None for x in v]


class McapSink(Sink):
    """Writes the run as MCAP (module docstring): a PoseWithCovarianceStamped (ROS ENU/FLU), JSON estimates with
    their covariance, innovations and events (foxglove.Log). Open it in Foxglove or PlotJuggler."""

    name = "mcap"
    suffixes = (".mcap",)

    class Params(Params):
        path: str = Field(description="output file (.mcap)")
        frame_id: str = Field("odom", description="the pose's ROS world frame (frame_id of /fusion/pose)")

    def __init__(self, params: Params, context: BuildContext | None = None):
        super().__init__(params, context)
        from mcap.writer import CompressionType, Writer

        self.layout: StateLayout | None = self.context.layout
        self._out: OutputFile | None = OutputFile(self.params.path, "wb", what="MCAP output")
        self._w = Writer(_Counted(self._out), compression=CompressionType.ZSTD)
        self._w.start(profile="", library="fusion")
        self._json = {}
        for topic, schema in (("/fusion/estimate", ESTIMATE_SCHEMA), ("/fusion/innovation", INNOVATION_SCHEMA),
                              ("/fusion/events", LOG_SCHEMA)):
            sid = self._w.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
            self._json[topic] = self._w.register_channel(topic, "json", sid)
        self._pose = self._pose_channel()
        self._seq = 0
        self.rows = 0

    def _pose_channel(self):
        lay = self.layout
        if lay is None or "p" not in lay or lay["p"].stop - lay["p"].start != 3:
            return None
        from rosbags.typesys import Stores, get_typestore

        store = get_typestore(Stores.LATEST)
        msgdef, _ = store.generate_msgdef(POSE_TYPE, ros_version=2)
        sid = self._w.register_schema(POSE_TYPE, "ros2msg", msgdef.encode())
        cid = self._w.register_channel("/fusion/pose", "cdr", sid, {"frame": "ROS ENU world / FLU body (REP-103)"})
        return store, cid

    def _write(self, channel: int, t: float, data: bytes) -> None:
        self._seq += 1
        self._w.add_message(channel, log_time=_ns(t), data=data, publish_time=_ns(t), sequence=self._seq)

    def on_estimate(self, estimate: Estimate) -> None:
        if self._out is None:
            raise ValueError(f"MCAP sink {self.params.path} is closed")
        b = estimate.belief
        x, P = np.asarray(b.x, float), np.asarray(b.cov, float)
        names = self.layout.names if self.layout is not None else tuple(f"x{i}" for i in range(len(x)))
        sd = np.sqrt(np.clip(np.diag(P), 0.0, None))
        doc = {"t": estimate.t, "reason": estimate.reason, "sensor": estimate.sensor or "",
               "x": dict(zip(names, _finite(x.tolist()))), "sd": dict(zip(names, _finite(sd.tolist()))),
               "P": [_finite(row) for row in P.tolist()]}
        self._write(self._json["/fusion/estimate"], estimate.t, json.dumps(doc).encode())
        u = estimate.update
        if u is not None:
            inn = {"t": estimate.t, "sensor": estimate.sensor or "", "innovation": _finite(np.ravel(u.innovation).tolist()),
                   "S": [_finite(r) for r in np.atleast_2d(u.S).tolist()], "nis": u.nis if math.isfinite(u.nis) else None,
                   "accepted": bool(u.accepted)}
            self._write(self._json["/fusion/innovation"], estimate.t, json.dumps(inn).encode())
        if self._pose is not None and np.all(np.isfinite(x)):
            from fusion.sinks.mcap_pose import pose_message

            store, cid = self._pose
            msg = pose_message(store, self.layout, x, P, estimate.t, self.params.frame_id)
            self._write(cid, estimate.t, bytes(store.serialize_cdr(msg, POSE_TYPE)))
        self.rows += 1

    def on_event(self, event: Event) -> None:
        if self._out is None:
            return
        t = event.t if math.isfinite(event.t) else 0.0
        ns = _ns(t)
        doc = {"timestamp": {"sec": ns // 10**9, "nsec": ns % 10**9}, "level": LEVELS.get(event.kind, 2),
               "message": f"{event.kind}: {event.detail}", "name": event.sensor or "fusion", "file": "", "line": 0}
        self._write(self._json["/fusion/events"], t, json.dumps(doc).encode())

    def close(self) -> None:
        out, self._out = self._out, None
        if out is not None:
            self._w.finish()
            out.close()
