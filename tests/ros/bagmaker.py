"""Bags the ROS tests write with rosbags' own writers: a wheeled robot on flat ground (ROS frames: odom ENU,
base_link FLU) with an IMU, wheel odometry, a GPS, robot_localization's output as a reference, and static tf.

The truth is integrated at 200 Hz from a speed and a yaw rate given in closed form; sensors sample it with
seeded Gaussian noise whose sd each message's covariance states (so the covariances are right).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

G = 9.80665
ORIGIN = (48.0, 11.0, 500.0)   # lat, lon deg, alt m of the odom origin (arbitrary: nothing depends on it)


@dataclass
class Truth:
    t: np.ndarray                 # s from the start
    x: np.ndarray                 # ENU east, m
    y: np.ndarray                 # ENU north, m
    yaw: np.ndarray               # rad, ENU (0 east, counter-clockwise)
    v: np.ndarray                 # forward speed m/s
    r: np.ndarray                 # yaw rate rad/s
    a: np.ndarray                 # forward acceleration m/s^2


def truth(duration: float = 40.0, rate: float = 200.0) -> Truth:
    t = np.arange(0.0, duration + 1e-9, 1.0 / rate)
    v = 1.5 * (1 - np.cos(np.pi * np.clip(t / 4.0, 0, 1))) / 2          # smooth start to 1.5 m/s over 4 s
    a = 1.5 * np.pi / 8.0 * np.sin(np.pi * np.clip(t / 4.0, 0, 1)) * (t < 4.0)
    r = 0.25 * np.sin(2 * np.pi * t / 20.0) * (t > 4.0)
    dt = 1.0 / rate
    yaw = np.concatenate([[0.3], 0.3 + np.cumsum(0.5 * (r[1:] + r[:-1]) * dt)])
    vx, vy = v * np.cos(yaw), v * np.sin(yaw)
    x = np.concatenate([[0.0], np.cumsum(0.5 * (vx[1:] + vx[:-1]) * dt)])
    y = np.concatenate([[0.0], np.cumsum(0.5 * (vy[1:] + vy[:-1]) * dt)])
    return Truth(t, x, y, yaw, v, r, a)


@dataclass
class Spec:
    """What to write: rates (Hz), noise sd, and the bad-bag knobs."""

    imu_hz: float = 50.0
    odom_hz: float = 20.0
    gps_hz: float = 5.0
    ref_hz: float = 10.0
    start_ns: int = 1_700_000_000_000_000_000
    receive_delay_s: float = 0.01
    gyro_sd: float = 0.01
    accel_sd: float = 0.05
    yaw_sd: float = 0.02
    odom_v_sd: float = 0.05
    odom_r_sd: float = 0.02
    gps_sd: float = 0.5
    imu_arm: tuple[float, float, float] = (0.1, 0.0, 0.2)
    imu_mount: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)   # imu_link in base_link, [w x y z] FLU
    zero_stamps: int = 0           # the first N IMU messages stamped 0
    backwards: bool = False        # one odometry stamp earlier than the one before
    zero_cov: bool = False         # wheel odometry with all-zero covariances
    empty_topic: bool = False      # a /unused topic without messages
    unknown_topic: bool = False    # a std_msgs/Float64 topic
    mag_range: bool = False        # a /mag MagneticField (1 Hz) and a /sonar Range (every 4th out of range)
    tf_on_tf: bool = False         # ROS 1 style: the mounts repeated on /tf each second, with odom -> base_link
    seed: int = 1
    extra: dict = field(default_factory=dict)


def _quat_yaw(yaw: float) -> tuple[float, float, float, float]:
    return np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)      # w x y z


class _Msgs:
    def __init__(self, store):
        self.s = store
        self.T = store.types

    def header(self, ns: int, frame: str):
        H = self.T["std_msgs/msg/Header"]
        stamp = self.T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
        if "seq" in H.__dataclass_fields__:    # ROS 1
            return H(seq=0, stamp=stamp, frame_id=frame)
        return H(stamp=stamp, frame_id=frame)

    def vec(self, x, y, z):
        return self.T["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))

    def quat(self, w, x, y, z):
        return self.T["geometry_msgs/msg/Quaternion"](x=float(x), y=float(y), z=float(z), w=float(w))

    def pose(self, x, y, yaw, cov):
        P = self.T["geometry_msgs/msg/Pose"](position=self.T["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0),
                                            orientation=self.quat(*_quat_yaw(yaw)))
        return self.T["geometry_msgs/msg/PoseWithCovariance"](pose=P, covariance=np.asarray(cov, float).ravel())

    def twist(self, vx, r, cov):
        tw = self.T["geometry_msgs/msg/Twist"](linear=self.vec(vx, 0, 0), angular=self.vec(0, 0, r))
        return self.T["geometry_msgs/msg/TwistWithCovariance"](twist=tw, covariance=np.asarray(cov, float).ravel())


def messages(store, spec: Spec, tr: Truth):
    """(topic, msgtype, stamp ns, receive ns, message) in receive order."""
    import pymap3d

    rng = np.random.default_rng(spec.seed)
    M = _Msgs(store)
    out = []

    def at(hz):
        idx = np.arange(0, len(tr.t), int(round(200.0 / hz)))
        return idx

    def ns(i):
        return spec.start_ns + int(round(tr.t[i] * 1e9))

    delay = int(spec.receive_delay_s * 1e9)
    from scipy.spatial.transform import Rotation

    wm, xm, ym, zm = spec.imu_mount
    Cm = Rotation.from_quat([xm, ym, zm, wm])          # the IMU's axes in the body: its data is Cm^-1 of the body's
    M_T = Cm.inv().as_matrix()                         # body-axis covariances into the IMU's axes
    for k, i in enumerate(at(spec.imu_hz)):
        f = Cm.inv().apply(np.array([tr.a[i], tr.v[i] * tr.r[i], G])) + rng.normal(0, spec.accel_sd, 3)
        w = Cm.inv().apply(np.array([0.0, 0.0, tr.r[i]])) + rng.normal(0, spec.gyro_sd, 3)
        yaw = tr.yaw[i] + rng.normal(0, spec.yaw_sd)
        x, y, z, qw = (Rotation.from_euler("z", yaw) * Cm).as_quat()     # the IMU frame's attitude in ENU
        stamp = 0 if k < spec.zero_stamps else ns(i)
        msg = M.T["sensor_msgs/msg/Imu"](header=M.header(stamp, "imu_link"), orientation=M.quat(qw, x, y, z),
                                         orientation_covariance=(M_T @ np.diag([1e-4, 1e-4, spec.yaw_sd ** 2]) @
                                                                 M_T.T).ravel(),
                                         angular_velocity=M.vec(*w),
                                         angular_velocity_covariance=np.diag([spec.gyro_sd ** 2] * 3).ravel(),
                                         linear_acceleration=M.vec(*f),
                                         linear_acceleration_covariance=np.diag([spec.accel_sd ** 2] * 3).ravel())
        out.append(("/imu/data", "sensor_msgs/msg/Imu", stamp, ns(i) + delay, msg))
    px = py = 0.0
    pyaw = tr.yaw[0]
    last = None
    for k, i in enumerate(at(spec.odom_hz)):
        v = tr.v[i] + rng.normal(0, spec.odom_v_sd)
        r = tr.r[i] + rng.normal(0, spec.odom_r_sd)
        if last is not None:
            dt = tr.t[i] - tr.t[last]
            pyaw += r * dt
            px += v * np.cos(pyaw) * dt
            py += v * np.sin(pyaw) * dt
        last = i
        pc = np.diag([0.01, 0.01, 1e6, 1e6, 1e6, 0.01]) * (0 if spec.zero_cov else 1)
        tc = np.diag([spec.odom_v_sd ** 2, 1e-3, 1e6, 1e6, 1e6, spec.odom_r_sd ** 2]) * (0 if spec.zero_cov else 1)
        stamp = ns(i)
        if spec.backwards and k == 10:
            stamp -= int(0.2e9)
        msg = M.T["nav_msgs/msg/Odometry"](header=M.header(stamp, "odom"), child_frame_id="base_link",
                                           pose=M.pose(px, py, pyaw, pc), twist=M.twist(v, r, tc))
        out.append(("/wheel/odometry", "nav_msgs/msg/Odometry", stamp, ns(i) + delay, msg))
    for i in at(spec.gps_hz):
        e, n = tr.x[i] + rng.normal(0, spec.gps_sd), tr.y[i] + rng.normal(0, spec.gps_sd)
        u = rng.normal(0, spec.gps_sd)
        lat, lon, alt = pymap3d.enu2geodetic(e, n, u, *ORIGIN)
        st = M.T["sensor_msgs/msg/NavSatStatus"](status=0, service=1)
        msg = M.T["sensor_msgs/msg/NavSatFix"](header=M.header(ns(i), "gps_link"), status=st, latitude=float(lat),
                                               longitude=float(lon), altitude=float(alt),
                                               position_covariance=np.diag([spec.gps_sd ** 2] * 3).ravel(),
                                               position_covariance_type=2)
        out.append(("/gps/fix", "sensor_msgs/msg/NavSatFix", ns(i), ns(i) + 3 * delay, msg))
    for i in at(spec.ref_hz):
        msg = M.T["nav_msgs/msg/Odometry"](header=M.header(ns(i), "odom"), child_frame_id="base_link",
                                           pose=M.pose(tr.x[i], tr.y[i], tr.yaw[i], np.eye(6) * 1e-4),
                                           twist=M.twist(tr.v[i], tr.r[i], np.eye(6) * 1e-4))
        out.append(("/odometry/filtered", "nav_msgs/msg/Odometry", ns(i), ns(i) + delay, msg))
    if spec.mag_range:
        for k, i in enumerate(at(1.0)):
            mag = M.T["sensor_msgs/msg/MagneticField"](header=M.header(ns(i), "imu_link"),
                                                       magnetic_field=M.vec(2e-5, 1e-6, -4e-5),
                                                       magnetic_field_covariance=np.zeros(9))
            out.append(("/mag", "sensor_msgs/msg/MagneticField", ns(i), ns(i), mag))
            rng_ = 0.5 + 0.1 * k if k % 4 else 9.0     # 9 m: past max_range
            son = M.T["sensor_msgs/msg/Range"](header=M.header(ns(i), "sonar"), radiation_type=0, field_of_view=0.5,
                                               min_range=0.2, max_range=4.0, range=rng_)
            out.append(("/sonar", "sensor_msgs/msg/Range", ns(i), ns(i), son))
    if spec.unknown_topic:
        out.append(("/battery", "std_msgs/msg/Float64", spec.start_ns, spec.start_ns, M.T["std_msgs/msg/Float64"](data=12.1)))
    out.sort(key=lambda m: m[3])
    return out


def tf_static(store, spec: Spec, extra=(), moving=(), mounts: bool = True):
    """The /tf_static message: base_link -> imu_link (spec.imu_arm, spec.imu_mount), base_link -> gps_link, and
    ``extra`` (parent, child, (x y z), (w x y z)); ``moving`` transforms first, the mounts only with ``mounts``."""
    M = _Msgs(store)
    items = [*moving] + ([("base_link", "imu_link", spec.imu_arm, spec.imu_mount),
                          ("base_link", "gps_link", (0.0, 0.0, 0.5), (1.0, 0.0, 0.0, 0.0)), *extra] if mounts else [])
    ts = []
    for parent, child, t, q in items:
        tr = M.T["geometry_msgs/msg/Transform"](translation=M.vec(*t), rotation=M.quat(*q))
        ts.append(M.T["geometry_msgs/msg/TransformStamped"](header=M.header(spec.start_ns, parent),
                                                            child_frame_id=child, transform=tr))
    return M.T["tf2_msgs/msg/TFMessage"](transforms=ts)


def write_bag(path: Path, storage: str = "ros1", spec: Spec | None = None, duration: float = 40.0,
              tf_extra=()) -> Truth:
    """Write the robot's bag at ``path`` (``ros1``: a .bag file; ``sqlite3``/``mcap``: a ROS 2 bag folder)."""
    from rosbags.typesys import Stores, get_typestore

    spec = spec or Spec()
    tr = truth(duration)
    path = Path(path)
    if storage == "ros1":
        from rosbags.rosbag1 import Writer

        store = get_typestore(Stores.ROS1_NOETIC)
        if "tf2_msgs/msg/TFMessage" not in store.types:   # not in rosbags' noetic store: its one-line definition
            from rosbags.typesys import get_types_from_msg

            store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
        ser = store.serialize_ros1
        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        store = get_typestore(Stores.LATEST)
        ser = store.serialize_cdr
        writer = Writer(path, version=9,
                        storage_plugin=StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3)
    msgs = messages(store, spec, tr)
    with writer:
        conns = {}
        tf_topic = "/tf" if spec.tf_on_tf else "/tf_static"
        for topic, typ in [(tf_topic, "tf2_msgs/msg/TFMessage")] + sorted({(m[0], m[1]) for m in msgs}):
            conns[topic] = writer.add_connection(topic, typ, typestore=store)
        if spec.empty_topic:
            writer.add_connection("/unused", "sensor_msgs/msg/Imu", typestore=store)
        static = ser(tf_static(store, spec, tf_extra), "tf2_msgs/msg/TFMessage")
        if spec.tf_on_tf:
            for k, i in enumerate(range(0, len(tr.t), 20)):     # 10 Hz: the moving odom -> base_link, mounts at 1 Hz
                ns = spec.start_ns + int(round(tr.t[i] * 1e9))
                moving = [("odom", "base_link", (tr.x[i], tr.y[i], 0.0), _quat_yaw(tr.yaw[i]))]
                msgs.append((tf_topic, "tf2_msgs/msg/TFMessage", ns, ns,
                             tf_static(store, spec, tf_extra, moving, mounts=k % 10 == 0)))
            msgs.sort(key=lambda m: m[3])
        else:
            writer.write(conns[tf_topic], spec.start_ns, static)
        for topic, typ, _, recv, msg in msgs:
            writer.write(conns[topic], recv, ser(msg, typ))
    return tr


def storage_file(path: Path, storage: str) -> Path:
    """The file to give ``fusion import``: the .bag itself, or the ROS 2 bag's storage file."""
    if storage == "ros1":
        return Path(path)
    return next(Path(path).glob("*.mcap" if storage == "mcap" else "*.db3"))


if __name__ == "__main__":   # python tests/ros/bagmaker.py OUT [ros1|sqlite3|mcap] [DURATION_S]: the docs' example bag
    import sys

    storage = sys.argv[2] if len(sys.argv) > 2 else "ros1"
    write_bag(Path(sys.argv[1]), storage, duration=float(sys.argv[3]) if len(sys.argv) > 3 else 60.0)
    print(f"wrote {sys.argv[1]} ({storage})")
