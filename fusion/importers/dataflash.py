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

Units and multipliers are the log's own: those of the format characters, as pymavlink applies them
(``c`` = int16 x 0.01, ``L`` = int32 x 1e-7, ...); the ``FMTU`` records' multipliers of plain integer
fields (e.g. ``MAG``'s mGauss) and their units (``UNIT`` records) are applied here, and a field whose unit
is not the expected one (or a known conversion of it) is refused. Logs without ``FMTU`` records get the layouts' documented units.

Time: ``t = TimeUS / 1e6`` s, the autopilot's boot clock (as in MAVExplorer and Mission Planner); ``TimeMS``
in older logs.

Damage (fusion.importers.dataflash_tables): a message of an unknown type ends pymavlink's index, so the
reader resyncs past it and the skipped bytes are corruption (exit 2 unless ``--partial``); messages that
parse but are absurd (instance number, time) are skipped and said; byte-identical repeats after the clock
goes back (a log concatenated with itself) are dropped and said.
"""
from __future__ import annotations

import datetime as dt
import math
import os

import numpy as np

from fusion.api import ImportedLog, Importer, ImportRequest, InputError, Stream
from fusion.importers.common import (DEG, F32, GAUSS_TO_UT, LATLON_E7, earth_field_ned, make_stream, quat_from_euler,
                                     slerp_to)
from fusion.importers.coverage import imu_coverage, to_header
from fusion.importers.dataflash_tables import _BASE, collect, open_log
from fusion.importers.flight_events import dataflash_events

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


class DataflashImporter(Importer):
    """ArduPilot DataFlash (.bin) logs through pymavlink.

    IMU (all instances), GPS (+GPA accuracies), MAG (mGauss ->
    uT), BARO, and the onboard EKF as ``reference`` lines (XKF1/NKF1/EKF1 position and velocity NED, ATT
    attitude as a body-to-NED quaternion), with the log's own units and multipliers (FMTU). Times: boot s."""

    name = "dataflash"
    suffixes = (".bin",)
    sensors = ("imu", "gps", "mag", "baro", "reference")

    def read(self, path: str, request: ImportRequest) -> ImportedLog:
        types = sorted(t for t, fam in _FAMILY.items() if request.wants_family(fam)
                       or (t == "ATT" and request.wants_family("mag")))   # ATT: the field in NED (mag header)
        types += ["EV", "MODE", "ERR"]   # the flight's events (fusion.importers.flight_events)
        reader = open_log(path, request)
        log = ImportedLog()
        rows, units, vehicle, texts = collect(reader, path, types, request, log.notes)
        log.meta["source"] = f"{os.path.basename(path)} (ArduPilot DataFlash, read by pymavlink)"
        if vehicle:
            log.meta["vehicle"] = vehicle
        log.meta["time_zero"] = "0 s on the autopilot's boot clock (t = TimeUS / 1e6)"
        conv = _Units(units)
        log.messages = sorted(texts + dataflash_events(rows, vehicle), key=lambda m: m[0])
        notes = log.notes
        if getattr(reader, "fusion_damage", None):   # --partial: what was skipped, said
            notes.append(f"{reader.fusion_damage}: skipped, the messages around them read")
            log.meta["partial"] = f"{reader.fusion_damage}: skipped (--partial)"
        if getattr(reader, "fusion_cut", None) is not None:
            cut = (f"truncated: the last message, at byte {reader.fusion_cut}, is cut short by the end of the file "
                   f"at byte {reader.data_len} ({reader.data_len - reader.fusion_cut} byte(s) lost, and whatever "
                   "the log would have held after them); the messages before it imported (--partial)")
            notes.append(cut)
            log.meta["partial"] = "; ".join(filter(None, (log.meta.get("partial"), cut)))
        streams: list[Stream] = []
        missing: list[str] = []
        for fam, fn in (("imu", _imu), ("gps", _gps), ("mag", _mag), ("baro", _baro)):
            if not request.wants_family(fam):
                continue
            got = fn(rows, conv, request, notes)
            streams += [s for s in got if request.wants(s.sensor)]
            absent = sorted(n for n in request.sensors or () if n.rstrip("0123456789") == fam and n != fam
                            and n not in {s.sensor for s in got})
            if absent:   # --sensors imu9 of a log with two IMUs: said, never a silent drop
                raise InputError(f"{path}: --sensors {' '.join(absent)}: not in the log (its {fam} instances: "
                                 f"{', '.join(s.sensor for s in got) or 'none'})")
            if not got:
                missing.append(fam)
        utc = _start_utc(rows.get("GPS"))
        if utc:
            log.meta["start_utc"] = utc
        if request.wants_family("reference"):
            ref, origin = _reference(rows, conv, request, notes)
            if ref is None:
                missing.append("reference (ATT, XKF1/NKF1/EKF1)")
            else:
                streams.append(ref)
                if origin is not None:   # fusion.importers.flight refers the reference to the first fix
                    ref.meta["ekf_origin"] = f"{origin[0]:.7f} {origin[1]:.7f} {origin[2]:.2f}"
        att = rows.get("ATT")
        mag0 = next((s for s in streams if s.sensor == "mag" and len(s)), None)
        if att is not None and mag0 is not None:
            q = quat_from_euler(*[conv.column(att, "ATT", c) * DEG for c in ("Roll", "Pitch", "Yaw")])
            f = earth_field_ned(mag0.t, mag0.values, att["t"], q)
            if f is not None:
                mag0.meta["earth_field_ned"] = " ".join(f"{v:.3f}" for v in f)
                mag0.meta["earth_field_source"] = "mean of the samples rotated to NED by ATT (uT)"
        if missing:
            asked = [m for m in missing if request.sensors is not None and m.split()[0] in request.sensors]
            if asked:
                raise InputError(f"{path}: no data for {', '.join(asked)}")
            notes.append("not in the log: " + ", ".join(missing))
        to_header(streams, log.meta)
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
        s = make_stream(_name("imu", inst), ("ax", "ay", "az", "gx", "gy", "gz"), r["t"], v, request,
                        meta={"units": "m/s^2 (specific force) rad/s, body FRD", "message": mt}, notes=notes)
        s.meta.update(imu_coverage(s.t, s.values[:, 3:], None, mt))
        out.append(s)
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
        if inst in gpa and len(gpa[inst][1]["t"]) and len(t):
            gmt, a = gpa[inst]
            hv = _gpa_per_fix(t, a["t"], [conv.column(a, gmt, c) for c in ("HAcc", "VAcc")],
                              _name("gps", inst), notes)
            for name, col in zip(("hacc", "vacc"), hv):
                fields.append(name)
                cols.append(col)
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


def _gpa_per_fix(t: np.ndarray, t_gpa: np.ndarray, columns: list[np.ndarray], name: str,
                 notes: list[str]) -> list[np.ndarray]:
    """The receiver accuracies (m) of each GPS sample at times ``t``: the GPA record written with it (the same
    TimeUS), else the last GPA before it within 1.5 s (a logger that dropped a record: its accuracy changes
    slowly), else 0, which the gps measurement reads as unknown (its configured floor). Each sample is
    matched on its own, so one missing GPA costs the accuracies of that sample, not of the whole log."""
    j = np.searchsorted(t_gpa, t, side="right") - 1      # the last GPA at or before each fix
    jj = np.clip(j, 0, len(t_gpa) - 1)
    exact = (j >= 0) & (t_gpa[jj] == t)
    near = (j >= 0) & ~exact & (t - t_gpa[jj] <= 1.5)
    keep = exact | near
    out = [np.where(keep, np.where(np.isfinite(c[jj]), c[jj], 0.0), 0.0) for c in columns]
    if np.any(near):
        notes.append(f"{name}: {int(np.sum(near))} sample(s) without their GPA record: the accuracy of the "
                     "previous one (within 1.5 s) is used")
    if np.any(~keep):
        notes.append(f"{name}: {int(np.sum(~keep))} sample(s) without a GPA record within 1.5 s: accuracy "
                     "unknown (0), the gps measurement's floor is used")
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
