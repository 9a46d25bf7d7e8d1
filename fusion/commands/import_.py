"""``fusion import FILE -o OUT.log``: a PX4 ULog, ArduPilot DataFlash log or CSV dataset into the log format.

(The module is ``import_`` because ``import`` is a Python keyword; the subcommand is ``import``.)
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from fusion.errors import ConfigError, InputError

HELP = "convert a PX4 .ulg, ArduPilot .bin, ROS bag (.bag, .db3, .mcap) or CSV dataset (with --map) into a recording"
DESCRIPTION = """\
Convert a flight log or dataset into the fusion log format: a header with the source file, the vehicle,
the origin and every sensor's units, '# fields' lines, then time-sorted messages: imu (m/s^2, rad/s, body
FRD), gps (lat, lon deg, alt m AMSL, NED velocity m/s, accuracies), mag (uT), baro, and 'reference' lines
with the vehicle's own estimate (NED position and velocity, body-to-NED quaternion [w x y z]), which
`fusion run` never fuses. A CSV needs a mapping file (--map): which column is time, which columns make
which sensor, unit scales, time offsets, and ground truth (written as 'truth' lines). The format is chosen
by the file's suffix (.ulg, .bin, .csv), or --format. Times are seconds from the log's start.
"""
EPILOG = """\
examples:
  fusion import flight.ulg -o flight.log
  fusion run configs/px4_ins_gps_mag.yaml --input flight.log          # agreement with PX4's EKF2
  fusion import 00000042.BIN -o flight.log --start 120 --end 300
  fusion run configs/ardupilot_ins_gps_mag.yaml --input flight.log    # agreement with ArduPilot's EKF3
  fusion import uwb_run3.csv --map docs/examples/uwb_dataset/mapping.yaml -o uwb_run3.log
  fusion import robot.bag -o robot.log --map topics.yaml              # ROS 1 or ROS 2 bag (docs/ros.md)

A flight log's recording has one origin, the first GPS fix with a 3-D fix and >= 6 satellites: the
reference positions are re-expressed about it, and one 'initial_attitude' line (the onboard attitude at
the first reference time) lets a config start in flight (docs/import.md).

importers available (--format NAME): see `fusion plugins --kind importer`; docs/import.md describes
each format, the mapping file and what a reference is.
"""


def register(subparsers) -> None:
    p = subparsers.add_parser("import", help=HELP, description=DESCRIPTION, epilog=EPILOG,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", metavar="FILE", help="log or dataset to read (.ulg, .bin, .csv, .bag, .db3, .mcap, a ROS 2 bag folder)")
    p.add_argument("-o", "--output", metavar="OUT.log", required=True,
                   help="recording to write ('-' for stdout); an existing file needs --force")
    p.add_argument("--start", type=float, metavar="S", help="first time to keep, s from the log's start")
    p.add_argument("--end", type=float, metavar="S", help="last time to keep, s from the log's start")
    p.add_argument("--sensors", nargs="+", metavar="NAME",
                   help="only these sensors (e.g. imu gps mag baro reference; for a CSV the mapping's names); "
                        "only their data is read. Default: all")
    p.add_argument("--map", metavar="MAP.yaml", help="mapping file of a CSV (docs/import.md) or a ROS bag (docs/ros.md)")
    p.add_argument("--format", metavar="NAME", help="importer by name (default: by the file's suffix)")
    p.add_argument("--gps", choices=("fields", "nmea"), default="fields",
                   help="how GPS fixes are written: 'fields' (lat lon alt vn ve vd ..., default) or 'nmea' "
                        "(GGA + RMC sentences a fix, for configs whose GPS goes through the nmea decoder)")
    p.add_argument("--partial", action="store_true",
                   help="import a truncated or corrupt log as far as it reads (default: refuse it)")
    p.add_argument("--force", action="store_true", help="replace an existing output file")
    p.set_defaults(func=run)


def choose_importer(registry, path: str, name: str | None):
    """The importer class named ``name``, or the one whose suffix the file has."""
    if name:
        return registry.get("importer", name, where="--format")
    suffix = "".join(Path(path).suffixes[-1:]).lower()
    if Path(path).is_dir():   # a ROS 2 bag folder: read by the importer of its storage files
        suffix = next((f.suffix.lower() for f in sorted(Path(path).iterdir()) if f.suffix in (".db3", ".mcap")), "")
    entries = registry.entries("importer")
    for e in entries:
        if suffix in tuple(s.lower() for s in e.cls.suffixes):
            return e.cls
    known = ", ".join(f"{s} ({e.name})" for e in entries for s in e.cls.suffixes)
    raise InputError(f"{path}: no importer reads {suffix or 'files without a suffix'!r} files "
                     f"(known: {known}); choose one with --format NAME")


def _sensors(values: list[str] | None) -> frozenset[str] | None:
    if not values:
        return None
    names = [s.strip() for v in values for s in v.split(",") if s.strip()]
    if not names:
        raise ConfigError("--sensors: no sensor names given")
    return frozenset(names)


def run(args: argparse.Namespace) -> int:
    from fusion.api import ImportRequest
    from fusion.importers.clock_check import check_one_clock
    from fusion.importers.flight import prepare
    from fusion.importers.writer import write_log
    from fusion.outputs import check_outputs
    from fusion.registry import default_registry

    for opt in ("start", "end"):
        v = getattr(args, opt)
        if v is not None and not math.isfinite(v):
            raise ConfigError(f"--{opt}: must be a finite number of seconds, got {v}")
    if args.start is not None and args.end is not None and args.end <= args.start:
        raise ConfigError(f"--end {args.end:g} must be after --start {args.start:g}")
    src = Path(args.file)
    if not src.exists():
        raise InputError(f"{src}: no such file")
    if src.is_dir() and not (src / "metadata.yaml").is_file():   # a ROS 2 bag is a folder with its metadata
        raise InputError(f"{src}: is a folder, not a log file")
    if args.map and not Path(args.map).is_file():
        if not Path(args.map).exists():
            raise InputError(f"{args.map}: no such mapping file")
        what = "a folder" if Path(args.map).is_dir() else "a device, FIFO or socket"
        raise InputError(f"--map {args.map}: {what}, not a readable regular file; give a mapping file "
                         "(YAML, docs/import.md)")
    cls = choose_importer(default_registry(), str(src), args.format)
    sensors = _sensors(args.sensors)
    if sensors is not None and cls.sensors:
        bad = sorted(s for s in sensors if s.rstrip("0123456789") not in cls.sensors)
        if bad:
            raise ConfigError(f"--sensors: {', '.join(bad)} not known to importer {cls.name!r} "
                              f"(it writes: {', '.join(cls.sensors)})")
        one = getattr(cls, "single_instance", False)
        numbered = sorted(s for s in sensors if s != s.rstrip("0123456789") and s.rstrip("0123456789") in cls.sensors)
        if one and numbered:   # PX4: only instance 0 of a topic is read (the one the estimator uses)
            raise ConfigError(f"--sensors {' '.join(numbered)}: importer {cls.name!r} reads only instance 0 of each "
                              f"topic (it writes: {', '.join(cls.sensors)})")
    if args.gps == "nmea" and not getattr(cls, "flight_log", True):
        raise ConfigError(f"--gps nmea: importer {cls.name!r} writes its GPS as local NED fixes with their covariance, "
                          "not as a flight log's fields (docs/ros.md)")
    if args.map and not getattr(cls, "takes_map", cls.name == "csv"):
        raise ConfigError(f"--map: a mapping file applies to CSV files and ROS bags, not to {cls.name!r} logs")
    check_outputs({"-o": args.output}, [str(src)] + ([args.map] if args.map else []), force=args.force)
    request = ImportRequest(start=args.start, end=args.end, sensors=sensors, mapping=args.map,
                            allow_partial=args.partial)
    try:
        log = cls().read(str(src), request)
    except InputError as exc:
        if str(src) in str(exc) or src.name in str(exc):
            raise
        raise InputError(f"{src}: {exc}") from exc     # every input error names the file
    except (KeyError, IndexError, ValueError, TypeError, OverflowError, UnicodeDecodeError) as exc:
        # a file whose content the importer's format reader did not expect (a field missing, a bad count):
        # the user's file, not a bug of ours, in every case met so far; --debug shows the traceback
        raise InputError(f"{src}: unexpected content for the {cls.name} importer ({type(exc).__name__}: {exc})") from exc
    if sensors is not None and cls.sensors:
        have = {s.sensor for s in log.streams}
        absent = sorted(s for s in sensors if s not in cls.sensors and s not in have)
        if absent:   # never a silent drop of a sensor asked for by name (imu9 of a log with two IMUs)
            fams = {s.rstrip("0123456789") for s in absent}
            others = sorted(s for s in have if s.rstrip("0123456789") in fams)
            raise InputError(f"{src}: --sensors {' '.join(absent)}: not in the log"
                             + (f" (it has: {', '.join(others)})" if others else ""))
    streams = [s for s in log.streams if len(s)]
    if not streams:
        span = ""
        if args.start is not None or args.end is not None:
            span = f" between --start {args.start} and --end {args.end}"
        raise InputError(f"{src}: no samples to write{span}" + (f" ({'; '.join(log.notes)})" if log.notes else ""))
    log.streams = streams
    check_one_clock(str(src), streams)   # every sensor overlaps the IMU's span, else exit 2 naming it
    if getattr(cls, "flight_log", True):
        prepare(log)      # one origin for the GPS and the reference; the onboard attitude to start in flight
    streams = [s for s in log.streams if len(s)]
    if args.gps == "nmea":
        from fusion.importers.nmea import as_nmea
        streams = [as_nmea(s, log.meta.get("start_utc"), log.notes) if s.sensor.rstrip("0123456789") == "gps" and
                   s.values is not None else s for s in streams]
    log.streams = streams
    t0 = min(float(s.t.min()) for s in streams)
    t1 = max(float(s.t.max()) for s in streams)
    log.meta.setdefault("duration", f"{t1 - t0:.3f}")
    if "partial" in log.meta:
        log.meta["partial"] += f"; the imported data end at t {t1:.3f} s"
    if args.start is not None or args.end is not None:
        log.meta["span"] = f"--start {args.start} --end {args.end} (s)"
    inputs = [str(src)] + ([args.map] if args.map else []) + list(log.inputs)
    n, size = write_log(log, args.output, inputs, force=args.force)
    for note in log.notes:
        print(f"fusion import: {note}", file=sys.stderr)
    counts = ", ".join(f"{s.sensor} {len(s)}" for s in streams)
    where = "stdout" if args.output == "-" else args.output
    print(f"wrote {where}: {n} lines ({counts}), t {t0:.3f}..{t1:.3f} s, {size / 1e3:.0f} kB", file=sys.stderr)
    return 0
