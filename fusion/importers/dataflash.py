"""Importer ``dataflash``: ArduPilot DataFlash logs (``.bin``) through pymavlink.

Messages read (only those of the requested sensors: pymavlink's index skips the others):

- ``imu``, ``imu2``, ...: ``IMU`` (instance field ``I``, or the older ``IMU2``/``IMU3`` types): ``AccX..Z``
  m/s^2 specific force and ``GyrX..Z`` rad/s, body FRD.
- ``gps``, ``gps2``: ``GPS``/``GPS2``: ``Lat``/``Lng`` deg, ``Alt`` m AMSL, velocity NED from ``Spd`` (m/s),
  ``GCrs`` (deg) and ``VZ`` (m/s, down), ``hacc``/``vacc`` from the ``GPA`` message of the same time when the
  log has it; samples without a fix (``Status`` < 2) dropped.
- ``mag``, ``mag2``, ...: ``MAG``: ``MagX..Z`` (mGauss in the log: int16 with multiplier 1e-3 to Gauss) to uT.
- ``baro``, ``baro2``: ``BARO``/``BAR2``: ``Alt`` m (relative), ``Press`` Pa, ``Temp`` degC.
- ``reference``: the onboard EKF: ``XKF1`` (lowest core ``C``), else ``NKF1``, else ``EKF1``: ``PN PE PD`` m and
  ``VN VE VD`` m/s NED from the EKF origin (``ORGN`` type 0 gives it), with the attitude of ``ATT``
  (``Roll Pitch Yaw`` deg, ZYX) interpolated to the EKF's times and turned into a body-to-NED quaternion.
  Without an EKF message: attitude only, from ``ATT``.

Units and multipliers are the log's own: pymavlink applies those of the format characters (``c`` = int16 x
0.01, ``L`` = int32 x 1e-7, ...); the ``FMTU`` records' multipliers of plain integer fields (e.g. ``MAG``'s
mGauss) and their units (``UNIT`` records) are applied here, and a field whose unit is not the expected one
(or a known conversion of it) is refused. Logs without ``FMTU`` records get the layouts' documented units.

Time: ``t = TimeUS / 1e6`` s, the autopilot's boot clock (as in MAVExplorer and Mission Planner); ``TimeMS``
in older logs.
"""
from __future__ import annotations

import datetime as dt
import math
import os

import numpy as np

from fusion.api import ImportedLog, Importer, ImportRequest, InputError, Stream
from fusion.importers.common import (DEG, F32, GAUSS_TO_UT, LATLON_E7, make_stream, quat_from_euler, silenced,
                                     slerp_to)

# unit label (UNIT record) -> (our unit, factor) per quantity
_CONVERT = {
    "accel": {"m/s/s": 1.0, "m/s^2": 1.0},
    "gyro": {"rad/s": 1.0, "deg/s": DEG},
    "mag": {"Gauss": GAUSS_TO_UT, "G": GAUSS_TO_UT, "mGauss": GAUSS_TO_UT * 1e-3, "uT": 1.0, "T": 1e6},
    "m": {"m": 1.0},
    "m/s": {"m/s": 1.0},
    "deg": {"deg": 1.0, "rad": 1.0 / DEG, "degheading": 1.0},
    "Pa": {"Pa": 1.0, "hPa": 100.0, "mbar": 100.0},
    "degC": {"degC": 1.0},
    "latlon": {"deglatitude": 1.0, "deglongitude": 1.0, "deg": 1.0},
    "-": {},
}
# (message, column) -> (quantity, default multiplier when the log has no FMTU for the message)
_FIELDS = {
    **{("IMU", f"{q}{a}"): (k, 1.0) for q, k in (("Acc", "accel"), ("Gyr", "gyro")) for a in "XYZ"},
    **{("MAG", f"Mag{a}"): ("mag", 1e-3) for a in "XYZ"},
    ("GPS", "Lat"): ("latlon", 1.0), ("GPS", "Lng"): ("latlon", 1.0), ("GPS", "Alt"): ("m", 1.0),
    ("GPS", "Spd"): ("m/s", 1.0), ("GPS", "GCrs"): ("deg", 1.0), ("GPS", "VZ"): ("m/s", 1.0),
    ("GPA", "HAcc"): ("m", 1.0), ("GPA", "VAcc"): ("m", 1.0),
    ("BARO", "Alt"): ("m", 1.0), ("BARO", "Press"): ("Pa", 1.0), ("BARO", "Temp"): ("degC", 1.0),
    **{("ATT", c): ("deg", 1.0) for c in ("Roll", "Pitch", "Yaw")},
    **{("EKF", c): ("deg", 1.0) for c in ("Roll", "Pitch", "Yaw")},
    **{("EKF", c): ("m/s", 1.0) for c in ("VN", "VE", "VD")},
    **{("EKF", c): ("m", 1.0) for c in ("PN", "PE", "PD")},
    ("ORGN", "Lat"): ("latlon", 1.0), ("ORGN", "Lng"): ("latlon", 1.0), ("ORGN", "Alt"): ("m", 1.0),
}
_FAMILY = {"IMU": "imu", "IMU2": "imu", "IMU3": "imu", "GPS": "gps", "GPS2": "gps", "GPA": "gps", "GPA2": "gps",
           "MAG": "mag", "MAG2": "mag", "MAG3": "mag", "BARO": "baro", "BAR2": "baro", "BAR3": "baro",
           "ATT": "reference", "XKF1": "reference", "NKF1": "reference", "EKF1": "reference",
           "ORGN": "reference"}
_EKFS = ("XKF1", "NKF1", "EKF1")
_BASE = {"IMU2": "IMU", "IMU3": "IMU", "GPS2": "GPS", "GPA2": "GPA", "MAG2": "MAG", "MAG3": "MAG", "BAR2": "BARO",
         "BAR3": "BARO", "XKF1": "EKF", "NKF1": "EKF", "EKF1": "EKF"}


class DataflashImporter(Importer):
    """ArduPilot DataFlash (.bin) logs through pymavlink.

    IMU (all instances), GPS (+GPA accuracies), MAG (mGauss ->
    uT), BARO, and the onboard EKF as ``reference`` lines (XKF1/NKF1/EKF1 position and velocity NED, ATT
    attitude as a body-to-NED quaternion), with the log's own units and multipliers (FMTU). Times: boot s."""

    name = "dataflash"
    suffixes = (".bin",)
    sensors = ("imu", "gps", "mag", "baro", "reference")

    def read(self, path: str, request: ImportRequest) -> ImportedLog:
        types = sorted(t for t, fam in _FAMILY.items() if request.wants_family(fam))
        reader = _open(path, request)
        rows, units, vehicle = _collect(reader, path, types, request)
        log = ImportedLog()
        log.meta["source"] = f"{os.path.basename(path)} (ArduPilot DataFlash, read by pymavlink)"
        if vehicle:
            log.meta["vehicle"] = vehicle
        log.meta["time_zero"] = "0 s on the autopilot's boot clock (t = TimeUS / 1e6)"
        conv = _Units(units)
        notes = log.notes
        streams: list[Stream] = []
        missing: list[str] = []
        for fam, fn in (("imu", _imu), ("gps", _gps), ("mag", _mag), ("baro", _baro)):
            if not request.wants_family(fam):
                continue
            got = fn(rows, conv, request, notes)
            streams += [s for s in got if request.wants(s.sensor)]
            if not got:
                missing.append(fam)
        gps0 = next((s for s in streams if s.sensor == "gps" and len(s)), None)
        utc = _start_utc(rows.get("GPS", []))
        if utc:
            log.meta["start_utc"] = utc
        if request.wants_family("reference"):
            ref, origin = _reference(rows, conv, request, notes)
            if ref is None:
                missing.append("reference (ATT, XKF1/NKF1/EKF1)")
            else:
                streams.append(ref)
            if origin is not None:
                log.meta["origin"] = f"{origin[0]:.7f} {origin[1]:.7f} {origin[2]:.2f}"
                log.meta["origin_source"] = "the EKF origin (ORGN type 0)"
        if "origin" not in log.meta and gps0 is not None:
            v = gps0.values[0]
            log.meta["origin"] = f"{v[0]:.7f} {v[1]:.7f} {v[2]:.2f}"
            log.meta["origin_source"] = "the first GPS fix imported"
        if missing:
            asked = [m for m in missing if request.sensors is not None and m.split()[0] in request.sensors]
            if asked:
                raise InputError(f"{path}: no data for {', '.join(asked)}")
            notes.append("not in the log: " + ", ".join(missing))
        log.streams = streams
        return log


# GPS - UTC leap seconds since 1980-01-06, by the date they took effect (IERS bulletins C)
_LEAPS = ((dt.datetime(2017, 1, 1, tzinfo=dt.timezone.utc), 18), (dt.datetime(2015, 7, 1, tzinfo=dt.timezone.utc), 17),
          (dt.datetime(2012, 7, 1, tzinfo=dt.timezone.utc), 16), (dt.datetime(2009, 1, 1, tzinfo=dt.timezone.utc), 15),
          (dt.datetime(2006, 1, 1, tzinfo=dt.timezone.utc), 14))


def _start_utc(gps_rows: list) -> str | None:
    """UTC at t = 0 from the first GPS row with a week number (GWk, GMS: GPS time), ISO 8601."""
    for t, d in gps_rows:
        wk, ms = int(d.get("GWk", 0) or 0), int(d.get("GMS", 0) or 0)
        if wk <= 0:
            continue
        gps_time = dt.datetime(1980, 1, 6, tzinfo=dt.timezone.utc) + dt.timedelta(weeks=wk, milliseconds=ms)
        leap = next((n for when, n in _LEAPS if gps_time >= when), 13)
        start = gps_time - dt.timedelta(seconds=leap) - dt.timedelta(seconds=t)
        return start.strftime("%Y-%m-%dT%H:%M:%S.%fZ")
    return None


def _open(path: str, request: ImportRequest):
    from pymavlink.DFReader import DFReader_binary

    try:
        with open(path, "rb") as fh:
            head = fh.read(3)
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if len(head) < 3 or head[:2] != b"\xa3\x95":
        raise InputError(f"{path}: not an ArduPilot DataFlash log (it does not start with a message header "
                         "0xA3 0x95; a text .log needs converting, a .tlog is MAVLink telemetry)")
    try:
        with silenced():
            reader = DFReader_binary(path)
    except Exception as exc:  # pymavlink raises plain errors on damaged FMT records
        raise InputError(f"{path}: damaged DataFlash log ({type(exc).__name__}: {exc})") from None
    if len(reader.formats) <= 1:
        raise InputError(f"{path}: not a DataFlash log: no FMT records")
    cut, gap, first_gap = _integrity(reader)
    if not request.allow_partial:
        if cut is not None:
            raise InputError(f"{path}: truncated: the last message, at byte {cut}, is cut short by the end of the "
                             f"file at byte {reader.data_len}; pass --partial to import what comes before it")
        if gap:
            raise InputError(f"{path}: corrupt: {gap} byte(s) belong to no message (the first at byte {first_gap}); "
                             "pass --partial to import the messages pymavlink could read")
    return reader


def _integrity(reader) -> tuple[int | None, int, int | None]:
    """(offset of a last message cut by the end of the file or None, bytes outside any message, first such
    byte) from pymavlink's index of message offsets."""
    offs, lens = [], []
    for mtype, o in enumerate(reader.offsets):
        if len(o) and mtype in reader.formats:
            offs.append(np.asarray(o, np.int64))
            lens.append(np.full(len(o), reader.formats[mtype].len, np.int64))
    if not offs:
        return None, 0, None
    o = np.concatenate(offs)
    n = np.concatenate(lens)
    order = np.argsort(o, kind="stable")
    o, n = o[order], n[order]
    end = o + n
    cut = int(o[-1]) if end[-1] > reader.data_len else None
    gaps = o[1:] - end[:-1]
    bad = np.flatnonzero(gaps > 0)
    lead = int(o[0])
    total = int(gaps[bad].sum()) + lead
    first = int(end[bad[0]]) if bad.size else (0 if lead else None)
    return cut, total, first


def _collect(reader, path: str, types: list[str], request: ImportRequest):
    """Rows per message type as dicts of columns (scaled by pymavlink's format multipliers), the units
    per (type, column) from FMTU/UNIT/MULT, and a vehicle description from VER or the first MSG."""
    want = set(types) | {"FMTU", "UNIT", "MULT", "MSG", "VER"}
    rows: dict[str, list[tuple[float, dict]]] = {t: [] for t in types}
    fmtu: dict[int, tuple[str, str]] = {}
    unit_label: dict[str, str] = {}
    mult: dict[str, float] = {}
    vehicle = ""
    stop_after = request.end + 2.0 if request.end is not None else math.inf  # messages are written ~in time order
    with silenced():
        while True:
            try:
                m = reader.recv_match(type=list(want))
            except Exception as exc:
                raise InputError(f"{path}: damaged DataFlash message near byte {getattr(reader, 'offset', '?')} "
                                 f"({type(exc).__name__}: {exc})") from None
            if m is None:
                break
            mt = m.get_type()
            if mt == "FMTU":
                fmtu[int(m.FmtType)] = (str(m.UnitIds), str(m.MultIds))
                continue
            if mt == "UNIT":
                unit_label[chr(int(m.Id))] = str(m.Label)
                continue
            if mt == "MULT":
                mult[chr(int(m.Id))] = float(f"{float(m.Mult):.7g}")
                continue
            if mt == "VER" and not vehicle:
                vehicle = " ".join(str(getattr(m, c, "")) for c in ("FWS",) if getattr(m, c, ""))
                continue
            if mt == "MSG":
                text = str(getattr(m, "Message", ""))
                if not vehicle and any(k in text for k in ("ArduCopter", "ArduPlane", "ArduRover", "ArduSub",
                                                            "Rover", "Copter", "Plane", "Blimp", "AntennaTracker")):
                    vehicle = text.strip()
                continue
            if mt not in rows:
                continue
            d = m.to_dict()
            if "TimeUS" in d:
                t = d["TimeUS"] / 1e6
            elif "TimeMS" in d:
                t = d["TimeMS"] / 1e3
            else:
                continue
            if t > stop_after:
                break
            rows[mt].append((t, d))
    units = {}
    for mtype, (uids, mids) in fmtu.items():
        fmt = reader.formats.get(mtype)
        if fmt is None:
            continue
        for i, col in enumerate(fmt.columns):
            label = unit_label.get(uids[i], "") if i < len(uids) else ""
            preset = fmt.msg_mults[i] is not None if i < len(fmt.msg_mults) else False
            mul = 1.0 if preset or i >= len(mids) else mult.get(mids[i], 1.0)
            units[(fmt.name, col)] = (label, mul or 1.0)
    return rows, units, vehicle


class _Units:
    """Scale of each (message, column) to our unit, from the log's FMTU or the layout's defaults."""

    def __init__(self, units: dict):
        self.units = units

    def factor(self, mtype: str, col: str) -> float:
        qty, default_mult = _FIELDS.get((_BASE.get(mtype, mtype), col), ("-", 1.0))
        have = self.units.get((mtype, col))
        if have is None:   # no FMTU for this message: the layout's documented unit (the table's first)
            return default_mult * (next(iter(_CONVERT[qty].values())) if _CONVERT[qty] else 1.0)
        label, mul = have
        if not label or qty == "-":
            return mul
        table = _CONVERT[qty]
        if label not in table:
            raise InputError(f"{mtype}.{col}: unit {label!r} in the log's FMTU records, expected one of "
                             f"{', '.join(table)}")
        return mul * table[label]

    def column(self, rows: list, mtype: str, col: str) -> np.ndarray:
        f = self.factor(mtype, col)
        return np.array([d.get(col, np.nan) for _, d in rows], float) * f


def _instances(rows: dict, names: tuple[str, ...]) -> dict[int, tuple[str, list]]:
    """{instance: (message type, rows)} of a sensor logged as one type with field ``I`` or as numbered types."""
    out: dict[int, tuple[str, list]] = {}
    for k, mt in enumerate(names):
        for t, d in rows.get(mt, []):
            inst = int(d["I"]) if "I" in d and k == 0 else k
            out.setdefault(inst, (mt, []))[1].append((t, d))
    return dict(sorted(out.items()))


def _name(family: str, inst: int) -> str:
    return family if inst == 0 else f"{family}{inst + 1}"


def _times(r: list) -> np.ndarray:
    return np.array([t for t, _ in r], float)


def _imu(rows, conv: _Units, request, notes) -> list[Stream]:
    out = []
    for inst, (mt, r) in _instances(rows, ("IMU", "IMU2", "IMU3")).items():
        v = np.column_stack([conv.column(r, mt, f"Acc{a}") for a in "XYZ"] + [conv.column(r, mt, f"Gyr{a}") for a in "XYZ"])
        out.append(make_stream(_name("imu", inst), ("ax", "ay", "az", "gx", "gy", "gz"), _times(r), v, request,
                               meta={"units": "m/s^2 (specific force) rad/s, body FRD", "message": mt}, notes=notes))
    return out


def _gps(rows, conv: _Units, request, notes) -> list[Stream]:
    out = []
    gpa = {inst: {t: d for t, d in r} for inst, (mt, r) in _instances(rows, ("GPA", "GPA2")).items()}
    for inst, (mt, r) in _instances(rows, ("GPS", "GPS2")).items():
        t = _times(r)
        spd, crs = conv.column(r, mt, "Spd"), conv.column(r, mt, "GCrs") * DEG
        cols = [conv.column(r, mt, "Lat"), conv.column(r, mt, "Lng"), conv.column(r, mt, "Alt"),
                spd * np.cos(crs), spd * np.sin(crs), conv.column(r, mt, "VZ")]
        fields = ["lat", "lon", "alt", "vn", "ve", "vd"]
        fmts = [LATLON_E7, LATLON_E7, ".2f", F32, F32, F32]
        acc = gpa.get(inst, {})
        if acc and all(tt in acc for tt, _ in r):
            gmt = "GPA" if inst == 0 or "GPA2" not in rows else "GPA2"
            for name, col in (("hacc", "HAcc"), ("vacc", "VAcc")):
                fields.append(name)
                cols.append(np.array([acc[tt].get(col, np.nan) for tt, _ in r], float) * conv.factor(gmt, col))
                fmts.append(F32)
        status = np.array([d.get("Status", 3) for _, d in r], float)
        fields += ["hdop", "fix", "nsat"]
        cols += [np.array([d.get("HDop", np.nan) for _, d in r], float), status,
                 np.array([d.get("NSats", 0) for _, d in r], float)]
        fmts += [F32, "d", "d"]
        ok = status >= 2
        if np.any(~ok):
            notes.append(f"{_name('gps', inst)}: {int(np.sum(~ok))} sample(s) without a fix (Status < 2) dropped")
        out.append(make_stream(_name("gps", inst), tuple(fields), t[ok], np.column_stack(cols)[ok], request,
                               tuple(fmts), meta={"units": "deg deg m(AMSL) m/s m/s m/s (NED)" +
                                                  (" m m" if "hacc" in fields else "") +
                                                  " - (hdop) - - (fix type, satellites)", "message": mt},
                               notes=notes))
    return out


def _mag(rows, conv: _Units, request, notes) -> list[Stream]:
    out = []
    for inst, (mt, r) in _instances(rows, ("MAG", "MAG2", "MAG3")).items():
        v = np.column_stack([conv.column(r, mt, f"Mag{a}") for a in "XYZ"])
        out.append(make_stream(_name("mag", inst), ("mx", "my", "mz"), _times(r), v, request,
                               meta={"units": "uT, body FRD (offsets applied)", "message": mt}, notes=notes))
    return out


def _baro(rows, conv: _Units, request, notes) -> list[Stream]:
    out = []
    for inst, (mt, r) in _instances(rows, ("BARO", "BAR2", "BAR3")).items():
        v = np.column_stack([conv.column(r, mt, c) for c in ("Alt", "Press", "Temp")])
        out.append(make_stream(_name("baro", inst), ("alt", "pressure", "temp"), _times(r), v, request,
                               meta={"units": "m (relative to the ground at start) Pa degC", "message": mt},
                               notes=notes))
    return out


def _reference(rows, conv: _Units, request, notes):
    origin = None
    org = [d for _, d in rows.get("ORGN", []) if int(d.get("Type", 0)) == 0]
    if org:
        d = org[0]
        o = tuple(float(d.get(c, np.nan)) * conv.factor("ORGN", c) for c in ("Lat", "Lng", "Alt"))
        if all(math.isfinite(v) for v in o) and abs(o[0]) <= 90 and abs(o[1]) <= 180:
            origin = o
        else:
            notes.append(f"reference: the ORGN record has no valid origin ({d})")
    att = rows.get("ATT", [])
    q_att = t_att = None
    if att:
        t_att = _times(att)
        e = [conv.column(att, "ATT", c) * DEG for c in ("Roll", "Pitch", "Yaw")]
        q_att = quat_from_euler(*e)
    meta = {"frame": "NED from the EKF origin; q body FRD to NED, [w x y z]"}
    for mt in _EKFS:
        r = rows.get(mt, [])
        if not r:
            continue
        if mt == "XKF1" and any("C" in d for _, d in r):
            core = min(int(d.get("C", 0)) for _, d in r)
            r = [(t, d) for t, d in r if int(d.get("C", 0)) == core]
            meta["source"] = f"ArduPilot EKF3 core {core} (XKF1)" + (" + ATT" if att else "")
        else:
            meta["source"] = f"ArduPilot EKF ({mt})" + (" + ATT" if att else "")
        t = _times(r)
        cols = [conv.column(r, mt, c) for c in ("PN", "PE", "PD", "VN", "VE", "VD")]
        if q_att is not None:
            q = slerp_to(t_att, q_att, t)
        else:
            q = quat_from_euler(*[conv.column(r, mt, c) * DEG for c in ("Roll", "Pitch", "Yaw")])
            meta["source"] += " (its own attitude: no ATT)"
        v = np.column_stack(cols + [q[:, i] for i in range(4)])
        return make_stream("reference", ("px", "py", "pz", "vx", "vy", "vz", "qw", "qx", "qy", "qz"), t, v, request,
                           meta=meta, notes=notes), origin
    if q_att is not None:
        meta["source"] = "ArduPilot AHRS attitude (ATT; no EKF position in the log)"
        return make_stream("reference", ("qw", "qx", "qy", "qz"), t_att, q_att, request, meta=meta,
                           notes=notes), origin
    return None, origin
