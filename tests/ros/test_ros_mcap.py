"""``fusion run --output run.mcap``: the MCAP read back with the ``mcap`` package (CRCs checked) against the CSV of
the same run; the pose channel decoded with rosbags as a ROS PoseWithCovarianceStamped in ENU / FLU."""
from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from bagmaker import write_bag
from ros_helpers import ROOT, fusion

EKF = ROOT / "docs" / "examples" / "ros" / "ekf.yaml"
pytestmark = pytest.mark.slow   # a bag written, imported, translated and run twice: ~13 s


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    d = tmp_path_factory.mktemp("mcap")
    write_bag(d / "robot.bag", "ros1", duration=15.0)
    (d / "map.yaml").write_text("reference: {topic: /odometry/filtered}\n")
    assert fusion("import", d / "robot.bag", "--map", d / "map.yaml", "-o", d / "robot.log") == 0
    assert fusion("import-config", EKF, "--recording", d / "robot.log", "-o", d / "robot.yaml") == 0
    cfg = (d / "robot.yaml").read_text().replace("on_update: false", "on_update: true")
    (d / "robot.yaml").write_text(cfg)
    for out in ("run.csv", "run.mcap"):
        assert fusion("run", d / "robot.yaml", "-o", d / out, "--quiet", "--no-progress") == 0
    return d


def _messages(path, topic):
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        return [(s, m) for s, _, m in reader.iter_messages(topics=[topic])]


def test_mcap_estimates_are_the_csv_rows(run):
    rows = list(csv.DictReader(open(run / "run.csv")))
    est = [json.loads(m.data) for _, m in _messages(run / "run.mcap", "/fusion/estimate")]
    assert len(est) == len(rows) > 100
    for r, e in zip(rows, est):
        assert float(r["t"]) == pytest.approx(e["t"], abs=1e-12)
        assert r["reason"] == e["reason"] and r["sensor"] == e["sensor"]
        for k, v in e["x"].items():   # the CSV prints repr(float): exact
            assert float(r[k]) == v
            assert float(r[f"sd_{k}"]) == pytest.approx(e["sd"][k], rel=1e-12)
        P = np.asarray(e["P"])
        np.testing.assert_allclose(np.sqrt(np.diag(P)), [e["sd"][k] for k in e["x"]], rtol=1e-12)
    inn = [json.loads(m.data) for _, m in _messages(run / "run.mcap", "/fusion/innovation")]
    assert len(inn) == sum(r["reason"] == "update" for r in rows)
    assert all(len(i["S"]) == len(i["innovation"]) for i in inn)


def test_mcap_summary_and_pose_in_ros_frames(run):
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    with open(run / "run.mcap", "rb") as fh:
        summary = make_reader(fh, validate_crcs=True).get_summary()
    topics = {c.topic: c for c in summary.channels.values()}
    assert {"/fusion/pose", "/fusion/estimate", "/fusion/innovation", "/fusion/events"} <= set(topics)
    assert summary.schemas[topics["/fusion/pose"].schema_id].name == "geometry_msgs/msg/PoseWithCovarianceStamped"
    assert summary.schemas[topics["/fusion/events"].schema_id].name == "foxglove.Log"
    store = get_typestore(Stores.LATEST)
    rows = list(csv.DictReader(open(run / "run.csv")))
    poses = _messages(run / "run.mcap", "/fusion/pose")
    assert len(poses) == len(rows)
    for (schema, m), r in list(zip(poses, rows))[::50]:
        msg = store.deserialize_cdr(m.data, schema.name)
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        # NED north = ENU y, east = ENU x; ENU yaw = pi/2 - NED yaw (two_d_mode: roll = pitch = 0)
        assert (p.x, p.y, p.z) == pytest.approx((float(r["py"]), float(r["px"]), -float(r["pz"])), abs=1e-12)
        yaw = 2 * math.atan2(q.z, q.w)
        assert math.remainder(yaw - (math.pi / 2 - float(r["yaw"])), 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
        cov = np.asarray(msg.pose.covariance).reshape(6, 6)
        assert cov[0, 0] == pytest.approx(float(r["sd_py"]) ** 2, rel=1e-9)
        assert cov[5, 5] == pytest.approx(float(r["sd_yaw"]) ** 2, rel=1e-9)
        assert m.log_time == round(float(r["t"]) * 1e9)


def test_quaternion_state_pose_orientation():
    from rosbags.typesys import Stores, get_typestore

    from fusion.api import StateLayout
    from fusion.sinks.mcap_pose import pose_message

    lay = StateLayout.parse("p:3 v:3 q:4")
    psi = 0.4          # NED yaw: 0.4 rad east of north; ENU yaw pi/2 - 0.4
    x = np.array([1.0, 2.0, -3.0, 0, 0, 0, math.cos(psi / 2), 0, 0, math.sin(psi / 2)])
    P = np.eye(10) * 0.01
    msg = pose_message(get_typestore(Stores.LATEST), lay, x, P, 1.5, "map")
    q = msg.pose.pose.orientation
    assert 2 * math.atan2(q.z, q.w) == pytest.approx(math.pi / 2 - psi)
    assert (msg.pose.pose.position.x, msg.pose.pose.position.y, msg.pose.pose.position.z) == (2.0, 1.0, 3.0)
    cov = np.asarray(msg.pose.covariance).reshape(6, 6)
    # P_qq = 0.01 I: the small-angle error 2 vec(q^-1 dq) has variance 4 x 0.01 per axis
    np.testing.assert_allclose(np.diag(cov)[3:], 0.04, rtol=1e-12)
