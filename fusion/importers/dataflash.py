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
        rows, units, vehicle, texts = _collect(reader, path, types, request)
        log = ImportedLog()
        log.meta["source"] = f"{os.path.basename(path)} (ArduPilot DataFlash, read by pymavlink)"
        if vehicle:
            log.meta["vehicle"] = vehicle
        log.meta["time_zero"] = "0 s on the autopilot's boot clock (t = TimeUS / 1e6)"
        conv = _Units(units)
        log.messages = texts
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
        utc = _start_utc(rows.get("GPS"))
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


def _start_utc(gps: dict | None) -> str | None:
    """UTC at t = 0 from the first GPS row with a week number (GWk, GMS: GPS time), ISO 8601."""
    if gps is None or "GWk" not in gps or "GMS" not in gps:
        return None
    for t, wk, ms in zip(gps["t"].tolist(), np.asarray(gps["GWk"]).tolist(), np.asarray(gps["GMS"]).tolist()):
        wk, ms = int(wk), int(ms)
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


_TIME = ("TimeUS", "TimeMS")
_NEEDED = {
    "IMU": ("I", "AccX", "AccY", "AccZ", "GyrX", "GyrY", "GyrZ"),
    "GPS": ("I", "Status", "GMS", "GWk", "NSats", "HDop", "Lat", "Lng", "Alt", "Spd", "GCrs", "VZ"),
    "GPA": ("I", "HAcc", "VAcc"), "MAG": ("I", "MagX", "MagY", "MagZ"), "BARO": ("I", "Alt", "Press", "Temp"),
    "ATT": ("Roll", "Pitch", "Yaw"), "EKF": ("C", "Roll", "Pitch", "Yaw", "VN", "VE", "VD", "PN", "PE", "PD"),
    "ORGN": ("Type", "Lat", "Lng", "Alt"), "FMTU": ("FmtType", "UnitIds", "MultIds"), "UNIT": ("Id", "Label"),
    "MULT": ("Id", "Mult"), "VER": ("FWS",), "MSG": ("Message",),
}
# DataFlash format characters -> numpy dtypes (pymavlink's FORMAT_TO_STRUCT, little endian, packed)
_DTYPE = {"b": "<i1", "B": "<u1", "M": "<u1", "h": "<i2", "H": "<u2", "c": "<i2", "C": "<u2", "i": "<i4",
          "I": "<u4", "e": "<i4", "E": "<u4", "L": "<i4", "f": "<f4", "d": "<f8", "g": "<f2", "q": "<i8",
          "Q": "<u8", "n": "S4", "N": "S16", "Z": "S64", "a": "S64"}


def _table(reader, name: str, request: ImportRequest | None) -> dict[str, np.ndarray] | None:
    """The columns this importer uses of every ``name`` message, read straight from the file's bytes at the
    offsets of pymavlink's index (vectorised: only these messages' bytes are touched, and of them only the
    time column before the span is cut), scaled by the format characters' multipliers as pymavlink scales
    them; ``t`` in s. None when the log has no such message."""
    mtype = reader.name_to_id.get(name) if hasattr(reader, "name_to_id") else None
    if mtype is None or mtype not in reader.formats or mtype >= len(reader.offsets):
        return None
    fmt = reader.formats[mtype]
    offs = np.asarray(reader.offsets[mtype], np.int64)
    offs = offs[offs + fmt.len <= reader.data_len]            # a message cut by the end of the file
    if offs.size == 0:
        return None
    buf = np.frombuffer(reader.data_map, np.uint8)
    pos, where = 3, {}
    for c, col in zip(fmt.format, fmt.columns):
        dtype = np.dtype(_DTYPE[c])
        where[col] = (pos, dtype, c)
        pos += dtype.itemsize

    def read(col: str, at: np.ndarray) -> np.ndarray:
        p0, dtype, c = where[col]
        raw = buf[at[:, None] + (p0 + np.arange(dtype.itemsize))]
        v = np.ascontiguousarray(raw).view(dtype).ravel()
        if dtype.kind == "S":
            return np.array([x.split(b"\0", 1)[0].decode("utf-8", "replace") for x in v.tolist()], object)
        mul = FORMAT_MULT.get(c)
        return v / (1.0 / mul) if mul is not None else v.astype(float)

    tcol = next((c for c in _TIME if c in where), None)
    out: dict[str, np.ndarray] = {}
    if tcol is not None:
        t = read(tcol, offs) / (1e6 if tcol == "TimeUS" else 1e3)
        if request is not None:
            keep = np.ones(len(t), bool)
            if request.start is not None:
                keep &= t >= request.start
            if request.end is not None:
                keep &= t <= request.end
            offs, t = offs[keep], t[keep]
        out["t"] = t
    elif request is not None:
        return None
    for col in _NEEDED.get(_BASE.get(name, name), ()):
        if col in where:
            out[col] = read(col, offs)
    out["_n"] = np.array(len(offs))
    return out


FORMAT_MULT = {"c": 0.01, "C": 0.01, "e": 0.01, "E": 0.01, "L": 1e-7}   # pymavlink's FORMAT_TO_STRUCT


def _collect(reader, path: str, types: list[str], request: ImportRequest):
    """Tables per message type (columns scaled by the format characters' multipliers), the units per
    (type, column) from FMTU/UNIT/MULT, and a vehicle description from VER or the first MSG."""
    rows: dict[str, dict[str, np.ndarray]] = {}
    for mt in types:
        tab = _table(reader, mt, request)
        if tab is not None and int(tab["_n"]):
            rows[mt] = tab
    meta = {n: _table(reader, n, None) for n in ("FMTU", "UNIT", "MULT", "VER", "MSG")}
    unit_label: dict[str, str] = {}
    mult: dict[str, float] = {}
    if meta["UNIT"] is not None and "Id" in meta["UNIT"]:
        unit_label = {chr(int(i) & 0xFF): str(lbl) for i, lbl in zip(meta["UNIT"]["Id"], meta["UNIT"].get("Label", ()))}
    if meta["MULT"] is not None and "Id" in meta["MULT"]:
        mult = {chr(int(i) & 0xFF): float(f"{float(m):.7g}") for i, m in zip(meta["MULT"]["Id"], meta["MULT"].get("Mult", ()))}
    vehicle = ""
    if meta["VER"] is not None and "FWS" in meta["VER"] and len(meta["VER"]["FWS"]):
        vehicle = str(meta["VER"]["FWS"][0]).strip()
    if not vehicle and meta["MSG"] is not None and "Message" in meta["MSG"]:
        for text in meta["MSG"]["Message"][:50]:
            if any(k in str(text) for k in ("ArduCopter", "ArduPlane", "ArduRover", "ArduSub", "Rover", "Copter",
                                            "Plane", "Blimp", "AntennaTracker")):
                vehicle = str(text).strip()
                break
    units = {}
    fm = meta["FMTU"]
    if fm is not None and "FmtType" in fm:
        for mtype, uids, mids in zip(fm["FmtType"], fm.get("UnitIds", ()), fm.get("MultIds", ())):
            fmt = reader.formats.get(int(mtype))
            if fmt is None:
                continue
            for i, col in enumerate(fmt.columns):
                label = unit_label.get(uids[i], "") if i < len(uids) else ""
                preset = i < len(fmt.format) and fmt.format[i] in FORMAT_MULT
                mul = 1.0 if preset or i >= len(mids) else mult.get(mids[i], 1.0)
                units[(fmt.name, col)] = (label, mul or 1.0)
    texts = []
    msg = meta["MSG"]
    if msg is not None and "Message" in msg and "t" in msg:
        for t, text in zip(msg["t"].tolist(), msg["Message"]):
            if (request.start is None or t >= request.start) and (request.end is None or t <= request.end):
                texts.append((t, str(text)))
    return rows, units, vehicle, texts


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

    def column(self, tab: dict, mtype: str, col: str) -> np.ndarray:
        return _col(tab, col) * self.factor(mtype, col)


def _n(tab: dict) -> int:
    return int(tab["_n"])


def _col(tab: dict, name: str, default: float = np.nan) -> np.ndarray:
    v = tab.get(name)
    return np.asarray(v, float) if v is not None else np.full(_n(tab), default)


def _take(tab: dict, mask: np.ndarray) -> dict:
    out = {k: v[mask] for k, v in tab.items() if k != "_n"}
    out["_n"] = np.array(int(np.sum(mask)))
    return out


def _instances(rows: dict, names: tuple[str, ...]) -> dict[int, tuple[str, dict]]:
    """{instance: (message type, table)} of a sensor logged as one type with field ``I`` or as numbered types."""
    out: dict[int, tuple[str, dict]] = {}
    for k, mt in enumerate(names):
        tab = rows.get(mt)
        if tab is None:
            continue
        if k == 0 and "I" in tab:
            inst = np.asarray(tab["I"], int)
            for i in np.unique(inst).tolist():
                out.setdefault(int(i), (mt, _take(tab, inst == i)))
        else:
            out.setdefault(k, (mt, tab))
    return dict(sorted(out.items()))


def _name(family: str, inst: int) -> str:
    return family if inst == 0 else f"{family}{inst + 1}"


def _imu(rows, conv: _Units, request, notes) -> list[Stream]:
    out = []
    for inst, (mt, r) in _instances(rows, ("IMU", "IMU2", "IMU3")).items():
        v = np.column_stack([conv.column(r, mt, f"Acc{a}") for a in "XYZ"] + [conv.column(r, mt, f"Gyr{a}") for a in "XYZ"])
        out.append(make_stream(_name("imu", inst), ("ax", "ay", "az", "gx", "gy", "gz"), r["t"], v, request,
                               meta={"units": "m/s^2 (specific force) rad/s, body FRD", "message": mt}, notes=notes))
    return out


def _gps(rows, conv: _Units, request, notes) -> list[Stream]:
    out = []
    gpa = _instances(rows, ("GPA", "GPA2"))
    for inst, (mt, r) in _instances(rows, ("GPS", "GPS2")).items():
        t = r["t"]
        spd, crs = conv.column(r, mt, "Spd"), conv.column(r, mt, "GCrs") * DEG
        cols = [conv.column(r, mt, "Lat"), conv.column(r, mt, "Lng"), conv.column(r, mt, "Alt"),
                spd * np.cos(crs), spd * np.sin(crs), conv.column(r, mt, "VZ")]
        fields = ["lat", "lon", "alt", "vn", "ve", "vd"]
        fmts = [LATLON_E7, LATLON_E7, ".2f", F32, F32, F32]
        if inst in gpa:                                   # GPA is written with the GPS message, same TimeUS
            gmt, a = gpa[inst]
            j = np.searchsorted(a["t"], t)
            jj = np.clip(j, 0, max(len(a["t"]) - 1, 0))
            if len(a["t"]) and np.all(a["t"][jj] == t):
                for name, col in (("hacc", "HAcc"), ("vacc", "VAcc")):
                    fields.append(name)
                    cols.append(conv.column(a, gmt, col)[jj])
                    fmts.append(F32)
        status = _col(r, "Status", 3.0)
        fields += ["hdop", "fix", "nsat"]
        cols += [_col(r, "HDop"), status, _col(r, "NSats", 0.0)]
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
        out.append(make_stream(_name("mag", inst), ("mx", "my", "mz"), r["t"], v, request,
                               meta={"units": "uT, body FRD (offsets applied)", "message": mt}, notes=notes))
    return out


def _baro(rows, conv: _Units, request, notes) -> list[Stream]:
    out = []
    for inst, (mt, r) in _instances(rows, ("BARO", "BAR2", "BAR3")).items():
        v = np.column_stack([conv.column(r, mt, c) for c in ("Alt", "Press", "Temp")])
        out.append(make_stream(_name("baro", inst), ("alt", "pressure", "temp"), r["t"], v, request,
                               meta={"units": "m (relative to the ground at start) Pa degC", "message": mt},
                               notes=notes))
    return out


def _reference(rows, conv: _Units, request, notes):
    origin = None
    org = rows.get("ORGN")
    if org is not None:
        first = np.flatnonzero(_col(org, "Type", 0.0) == 0)
        if first.size:
            i = first[0]
            o = tuple(float(_col(org, c)[i]) * conv.factor("ORGN", c) for c in ("Lat", "Lng", "Alt"))
            if all(math.isfinite(v) for v in o) and abs(o[0]) <= 90 and abs(o[1]) <= 180:
                origin = o
            else:
                notes.append(f"reference: the ORGN record has no valid origin ({o})")
    att = rows.get("ATT")
    q_att = t_att = None
    if att is not None:
        t_att = att["t"]
        q_att = quat_from_euler(*[conv.column(att, "ATT", c) * DEG for c in ("Roll", "Pitch", "Yaw")])
    meta = {"frame": "NED from the EKF origin; q body FRD to NED, [w x y z]"}
    for mt in _EKFS:
        r = rows.get(mt)
        if r is None:
            continue
        if mt == "XKF1" and "C" in r:
            core = int(np.min(r["C"]))
            r = _take(r, np.asarray(r["C"]) == core)
            meta["source"] = f"ArduPilot EKF3 core {core} (XKF1)" + (" + ATT" if att is not None else "")
        else:
            meta["source"] = f"ArduPilot EKF ({mt})" + (" + ATT" if att is not None else "")
        t = r["t"]
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
