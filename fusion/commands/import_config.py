"""``fusion import-config ekf.yaml -o fusion.yaml``: a robot_localization parameter file as a system YAML."""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from fusion.errors import ConfigError, InputError

HELP = "translate a robot_localization parameter file (ekf.yaml / ukf.yaml, ROS 1 or ROS 2) into a config"
DESCRIPTION = """\
Translate a robot_localization parameter file into a system YAML of the omni process (robot_localization's
15-state model) and the pose, twist and imu models, run by `fusion run` with the ekf or ukf. Frames are
converted from ROS ENU/FLU to NED/FRD (docs/ros.md). Every parameter that cannot be translated is listed.
"""
EPILOG = """\
examples:
  fusion import robot.bag -o robot.log
  fusion import-config ekf.yaml -o robot.yaml --recording robot.log
  fusion import-config ekf.yaml -o robot.yaml --recording robot.log --tf base_link imu_link 0 -0.3 0.52 -1.5708 0 1.5708
  fusion run robot.yaml
  fusion import-config test_ekf_localization_node_bag1.test --recording test1.bag -o bag1.yaml   # ROS 1 launch

--tf PARENT CHILD X Y Z ROLL PITCH YAW (m, rad; repeatable) mounts a sensor frame on the body frame, as a
launch file's static_transform_publisher does (note the order: ROLL PITCH YAW; ROS 1's positional
static_transform_publisher takes YAW PITCH ROLL). A recording made by `fusion import` of a bag already
carries the bag's /tf_static mounts; --tf overrides them.
"""


def register(subparsers) -> None:
    p = subparsers.add_parser("import-config", help=HELP, description=DESCRIPTION, epilog=EPILOG,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("params", metavar="EKF.yaml", help="robot_localization parameter file (YAML), or a ROS 1 launch "
                   "file (.launch, .test, .xml) whose ekf/ukf node and static_transform_publisher nodes are read")
    p.add_argument("-o", "--output", metavar="OUT.yaml", required=True, help="system YAML to write ('-': stdout)")
    p.add_argument("--recording", metavar="LOG", help="the bag (.bag, .db3, .mcap) or a recording `fusion import` "
                   "made of it: its sensors' names, frames and mounts are used, and the config replays it")
    p.add_argument("--tf", nargs=8, action="append", default=[], metavar=("PARENT", "CHILD", "X", "Y", "Z", "ROLL",
                   "PITCH", "YAW"), help="a static transform (m, rad), repeatable")
    p.add_argument("--filter", choices=("ekf", "ukf"), help="default: ukf for a file with alpha/kappa/beta, else ekf")
    p.add_argument("--name", default=None, help="the config's name (default: the parameter file's stem)")
    p.add_argument("--force", action="store_true", help="replace an existing output file")
    p.set_defaults(func=run)


def _tfs(values: list[list[str]]):
    from fusion.importers.rosbag_rl_config import Tf

    out = []
    for v in values:
        try:
            nums = [float(x) for x in v[2:]]
        except ValueError:
            raise ConfigError(f"--tf {' '.join(v)}: X Y Z ROLL PITCH YAW must be numbers (m, rad)") from None
        if not all(math.isfinite(x) for x in nums):
            raise ConfigError(f"--tf {' '.join(v)}: X Y Z ROLL PITCH YAW must be finite")
        out.append(Tf(v[0], v[1], tuple(nums[:3]), tuple(nums[3:])))  # type: ignore[arg-type]
    return out


LAUNCH_SUFFIXES = (".launch", ".test", ".xml")


def _expected(e: dict[str, float]) -> str:
    """The launch file's test expectation, said in both frames."""
    x, y, z = e.get("final_x", 0.0), e.get("final_y", 0.0), e.get("final_z", 0.0)
    tol = f" within {e['tolerance']:g} m" if "tolerance" in e else ""
    return (f"the launch file's test expects the final position x {x:g} y {y:g} z {z:g} m (ROS ENU){tol}: "
            f"px {y:g} py {x:g} pz {-z:g} m in this config's NED")


def run(args: argparse.Namespace) -> int:
    import yaml

    from fusion.importers.rosbag_rl_config import RecordingInfo, parameters, translate
    from fusion.outputs import OutputFile, check_outputs
    from fusion.yamlsource import load_yaml

    src = Path(args.params)
    if not src.is_file():
        raise InputError(f"{src}: no such parameter file")
    if args.recording and not Path(args.recording).exists():
        raise InputError(f"--recording {args.recording}: no such recording or bag")
    check_outputs({"-o": args.output}, [str(src)] + ([args.recording] if args.recording else []), force=args.force)
    tfs, expected, notes, kind = _tfs(args.tf), {}, [], None
    if src.suffix.lower() in LAUNCH_SUFFIXES:
        from fusion.importers.rosbag_launch import read_launch

        params, kind, launch_tfs, expected, notes = read_launch(str(src))
        layout = "ROS 1 launch file"
        tfs += launch_tfs              # --tf first: it overrides the launch file's
    else:
        params, layout = parameters(load_yaml(str(src)).data, str(src))
    rec = RecordingInfo.read(args.recording) if args.recording else None
    if rec is not None and args.output != "-":
        rel = Path(args.recording).resolve()
        try:
            rec.path = str(rel.relative_to(Path(args.output).resolve().parent))
        except ValueError:
            rec.path = str(rel)
    result = translate(params, layout, rec, tfs, args.filter or kind, args.name or src.stem)
    result.untranslated[:0] = notes
    head = [f"# {src.name} ({layout}) translated by fusion import-config (docs/ros.md)."]
    if expected:
        said = _expected(expected)
        head.append(f"# {said}")
        print(f"fusion import-config: {said}", file=sys.stderr)
    head += ["# Not translated:"] + [f"#   {line}" for line in result.untranslated] if result.untranslated else []
    text = "\n".join(head) + "\n" + yaml.safe_dump(result.config, sort_keys=False, default_flow_style=None, width=110)
    out = OutputFile(args.output, "w", what="config")
    try:
        out.write(text)
    except BaseException:
        out.discard()
        raise
    out.close()
    for line in result.untranslated:
        print(f"fusion import-config: not translated: {line}", file=sys.stderr)
    if args.output != "-":   # the translation must wire as fusion run will wire it
        from fusion.config import load_system

        try:
            load_system(args.output)
        except ConfigError as exc:
            raise ConfigError(f"{args.output}: written, but it does not wire (a translation this command should not "
                              f"make; please report it with the parameter file): {exc}") from None
    n = len(result.config["sensors"])
    print(f"wrote {'stdout' if args.output == '-' else args.output}: omni, {result.config['filter']['type']}, "
          f"{n} sensor(s) ({', '.join(result.config['sensors'])}); {len(result.untranslated)} parameter(s) not "
          "translated", file=sys.stderr)
    return 0
