"""robot_localization parameters from a ROS 1 launch file (``.launch``, ``.test``, ``.xml``): the ``<param>`` and
``<rosparam>`` elements of its ekf/ukf node, and the mounts of its ``static_transform_publisher`` nodes, as
robot_localization's own bag tests give them (``fusion import-config``, docs/ros.md).

``static_transform_publisher`` (tf and tf2_ros) takes ``x y z yaw pitch roll parent child [period]`` or ``x y z
qx qy qz qw parent child [period]``. A ``<test>`` element's ``final_x``/``final_y``/``final_z``/``tolerance``
params (the bag tests' expected final position, ROS world frame) are returned too, to be said to the user.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from typing import Any

import yaml

from fusion.errors import ConfigError

from .rosbag_rl_config import Tf

NODE_TYPES = {"ekf_localization_node": "ekf", "ukf_localization_node": "ukf", "ekf_node": "ekf", "ukf_node": "ukf"}


def _value(text: str | None) -> Any:
    if text is None:
        return None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return text


def _node_params(node: ET.Element, notes: list[str]) -> dict[str, Any]:
    params: dict[str, Any] = {}
    for el in node:
        if el.tag == "param" and el.get("name"):
            params[el.get("name").lstrip("~")] = _value(el.get("value", el.text))
        elif el.tag == "rosparam":
            if el.get("command", "load") == "load" and el.get("file"):
                notes.append(f"<rosparam file={el.get('file')!r}>: not read (give that file to import-config itself)")
                continue
            data = _value(el.text or "")
            if el.get("param"):
                params[el.get("param").lstrip("~")] = data
            elif isinstance(data, dict):
                params.update(data)
    return params


def _static_tf(args: str, where: str) -> Tf:
    """A Tf of ``x y z yaw pitch roll parent child [period]`` or ``x y z qx qy qz qw parent child [period]``."""
    words = args.split()
    nums: list[float] = []
    for w in words:
        try:
            nums.append(float(w))
        except ValueError:
            break
    rest = words[len(nums):]
    if len(rest) < 2 or len(nums) not in (6, 7):
        raise ConfigError(f"{where}: static_transform_publisher args {args!r}: expected x y z yaw pitch roll (or qx "
                          "qy qz qw) parent child [period]")
    if len(nums) == 7:
        from scipy.spatial.transform import Rotation

        yaw, pitch, roll = Rotation.from_quat(nums[3:7]).as_euler("ZYX")
    else:
        yaw, pitch, roll = nums[3:6]
    return Tf(rest[0].lstrip("/"), rest[1].lstrip("/"), tuple(nums[:3]),  # type: ignore[arg-type]
              (float(roll), float(pitch), float(yaw)))


def read_launch(path: str) -> tuple[dict[str, Any], str, list[Tf], dict[str, float], list[str]]:
    """(params, filter kind, static transforms, the test's expectations, notes) of a ROS 1 launch file."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise ConfigError(f"{path}: not a readable launch file (XML): {exc}") from None
    notes: list[str] = []
    nodes = [n for n in root.iter("node") if n.get("type") in NODE_TYPES]
    if not nodes:
        raise ConfigError(f"{path}: no robot_localization node (type {' or '.join(NODE_TYPES)}) in the launch file")
    if len(nodes) > 1:
        notes.append(f"{len(nodes)} robot_localization nodes: the first ({nodes[0].get('name')}) is translated")
    node = nodes[0]
    global_params = {el.get("name"): _value(el.get("value")) for el in root.findall("param") if el.get("name")}
    if global_params.get("/use_sim_time") is not None:
        notes.append("/use_sim_time: the bag's header stamps are the clock here")
    tfs = []
    for n in root.iter("node"):
        if n.get("type") == "static_transform_publisher" and n.get("args"):
            tfs.append(_static_tf(n.get("args"), f"{path}: node {n.get('name')}"))
    expected: dict[str, float] = {}
    for test in root.iter("test"):
        for el in test.findall("param"):
            if el.get("name") in ("final_x", "final_y", "final_z", "tolerance"):
                expected[el.get("name")] = float(el.get("value"))
    return _node_params(node, notes), NODE_TYPES[node.get("type")], tfs, expected, notes
