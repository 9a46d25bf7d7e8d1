"""Importer ``ulog``: PX4 ULog (``.ulg``) through pyulog.

Topics read (only those of the requested sensors; pyulog skips the others while parsing):

- ``imu``: ``sensor_combined`` (``gyro_rad`` rad/s, ``accelerometer_m_s2`` m/s^2 specific force, body FRD), at
  the gyro's sample time.
- ``gps``: ``vehicle_gps_position``, else ``sensor_gps``, in either layout: integer ``lat``/``lon`` in 1e-7 deg
  and ``alt`` in mm (older PX4), or float ``latitude_deg``/``longitude_deg`` and ``altitude_msl_m`` (newer);
  velocity NED m/s, ``eph``/``epv`` m. Samples without a 2-D/3-D fix are dropped.
- ``mag``: ``vehicle_magnetometer`` (calibrated, body FRD) else ``sensor_mag`` (raw, sensor frame), Gauss
  converted to uT.
- ``baro``: ``vehicle_air_data`` (altitude m, pressure Pa, temperature degC) else ``sensor_baro`` (pressure in
  Pa, or mbar in older firmware, converted; temperature).
- ``reference``: the onboard EKF's output, ``vehicle_local_position`` (x y z, vx vy vz, NED from the EKF's
  local origin) with the attitude of ``vehicle_attitude`` (``q``: Hamilton ``[w x y z]``, FRD to NED, as
  ours) interpolated (slerp) to its times. Only the elements the EKF flags valid are written (e.g. no
  ``px py`` before a horizontal fix): the set that writes the most values; a sample whose flags are not
  0/1 is corrupt and skipped with a note. ``initial_attitude``: the first valid attitude.

Time: ``t = (timestamp - start_timestamp) / 1e6`` s, i.e. seconds from the log's start on the autopilot's
clock (``timestamp_sample`` where the topic has it).
"""
from __future__ import annotations

import io
import os

import numpy as np

from fusion.api import ImportedLog, Importer, ImportRequest, InputError, Stream
from fusion.importers import px4_legacy
from fusion.importers.common import (F32, GAUSS_TO_UT, LATLON_E7, LATLON_F, earth_field_ned, in_span, make_stream,
                                     silenced)
from fusion.importers.coverage import imu_coverage, to_header
from fusion.importers.flight_events import px4_events
from fusion.importers.ulog_reference import _cols, _reference

TOPICS = {
    "imu": ("sensor_combined",),
    "gps": ("vehicle_gps_position", "sensor_gps"),
    "mag": ("vehicle_magnetometer", "sensor_mag"),
    "baro": ("vehicle_air_data", "sensor_baro"),
    "reference": ("vehicle_local_position", "vehicle_attitude"),
}


class _Reader(io.RawIOBase):
    """A file wrapper that remembers a short read: pyulog stops silently at a message cut by the end of the
    file, and this is how a truncated log is told from a complete one."""

    def __init__(self, fh):
        self._fh = fh
        self.cut_at: int | None = None

    def readable(self) -> bool:
        return True

    def read(self, n: int = -1) -> bytes:
        data = self._fh.read(n)
        if n is not None and n > 0 and 0 < len(data) < n:
            self.cut_at = self._fh.tell()
        return data

    def seek(self, *args) -> int:
        return self._fh.seek(*args)

    def tell(self) -> int:
        return self._fh.tell()


def _first(ulog, names: tuple[str, ...]):
    for name in names:
        for d in ulog.data_list:
            if d.name == name and d.multi_id == 0 and len(d.data.get("timestamp", ())) > 0:
                return d
    return None


class UlogImporter(Importer):
    """PX4 ULog (.ulg) logs through pyulog.

    IMU (sensor_combined), GPS (vehicle_gps_position / sensor_gps, both
    layouts), magnetometer (vehicle_magnetometer / sensor_mag, G -> uT), barometer (vehicle_air_data /
    sensor_baro) and the onboard EKF as ``reference`` lines (vehicle_local_position + vehicle_attitude, NED,
    q body-to-NED). Times in s from the log's start."""

    name = "ulog"
    suffixes = (".ulg",)
    sensors = ("imu", "gps", "mag", "baro", "reference")
    single_instance = True   # only multi_id 0 of a topic is read: ``--sensors imu2`` is refused by the command

    def read(self, path: str, request: ImportRequest) -> ImportedLog:
        ulog = _parse(path, request)
        t0 = int(ulog.start_timestamp)
        log = ImportedLog()
        info = ulog.msg_info_dict
        vehicle = " ".join(str(info[k]) for k in ("sys_name", "ver_hw") if info.get(k))
        log.meta["source"] = f"{os.path.basename(path)} (PX4 ULog, read by pyulog)"
        if vehicle:
            log.meta["vehicle"] = vehicle + _software(info)
        log.meta["time_zero"] = (f"{t0 / 1e6:.6f} s on the autopilot's boot clock (t = boot time - "
                                 f"{t0 / 1e6:.6f})")
        if ulog.fusion_partial:
            log.meta["partial"] = ulog.fusion_partial
            log.notes.append(ulog.fusion_partial)

        def tcol(d) -> np.ndarray:
            ts = d.data.get("timestamp_sample", d.data["timestamp"])
            return (np.asarray(ts, np.int64) - t0) / 1e6

        streams: list[Stream] = []
        missing: list[str] = []
        notes = log.notes
        if request.wants("imu"):
            d = _first(ulog, TOPICS["imu"])
            if d is None:
                missing.append("imu (sensor_combined)")
            else:
                gyro = px4_legacy.gyro_field(d.data) or "gyro_rad"
                v = _cols(d, [f"accelerometer_m_s2[{i}]" for i in range(3)] + [f"{gyro}[{i}]" for i in range(3)])
                t_imu = tcol(d)
                integral = (np.asarray(d.data["gyro_integral_dt"], float) * 1e-6
                            if "gyro_integral_dt" in d.data else None)
                rel = d.data.get("accelerometer_timestamp_relative")
                if rel is not None and np.any(np.asarray(rel) == 0x7FFFFFFF):   # RELATIVE_TIMESTAMP_INVALID
                    stale = np.asarray(rel) == 0x7FFFFFFF
                    notes.append(f"imu: {int(stale.sum())} sample(s) without a new accelerometer sample dropped")
                    v, t_imu = v[~stale], t_imu[~stale]
                    integral = None if integral is None else integral[~stale]
                s = make_stream("imu", ("ax", "ay", "az", "gx", "gy", "gz"), t_imu, v, request,
                                meta={"units": "m/s^2 (specific force) rad/s, body FRD",
                                      "topic": "sensor_combined"}, notes=notes)
                keep = in_span(t_imu, request) & np.all(np.isfinite(v), axis=1)
                s.meta.update(imu_coverage(s.t, s.values[:, 3:], None if integral is None else integral[keep],
                                           "gyro_integral_dt"))
                streams.append(s)
        if request.wants("gps"):
            d = _first(ulog, TOPICS["gps"])
            if d is None:
                missing.append("gps (vehicle_gps_position or sensor_gps)")
            else:
                s = _gps(d, tcol(d), request, notes)
                streams.append(s)
                if "time_utc_usec" in d.data:
                    utc = np.asarray(d.data["time_utc_usec"], np.int64)
                    ok = np.flatnonzero(utc > 0)
                    if ok.size:
                        import datetime as _dt
                        i = ok[0]
                        start = utc[i] / 1e6 - (int(d.data["timestamp"][i]) - t0) / 1e6
                        log.meta["start_utc"] = _dt.datetime.fromtimestamp(start, _dt.timezone.utc).strftime(
                            "%Y-%m-%dT%H:%M:%S.%fZ")
        combined = _first(ulog, ("sensor_combined",))
        if request.wants("mag"):
            d = _first(ulog, TOPICS["mag"])
            if d is None and px4_legacy.has_mag(combined):
                t_m, v_m = px4_legacy.combined_mag(combined, t0)
                streams.append(make_stream("mag", ("mx", "my", "mz"), t_m, v_m * GAUSS_TO_UT, request,
                                           meta={"units": "uT, body FRD, calibrated", "topic":
                                                 "sensor_combined (magnetometer_ga, an older layout)"}, notes=notes))
            elif d is None:
                missing.append("mag (vehicle_magnetometer or sensor_mag)")
            else:
                if d.name == "vehicle_magnetometer":
                    v, frame = _cols(d, [f"magnetometer_ga[{i}]" for i in range(3)]), "body FRD, calibrated"
                else:
                    v, frame = _cols(d, ["x", "y", "z"]), "sensor frame, uncalibrated (sensor_mag)"
                    notes.append("mag: the log has no vehicle_magnetometer: the raw sensor_mag is written (sensor "
                                 "frame, uncalibrated; it needs its rotation and calibration before a config fuses "
                                 "it, docs/import.md)")
                streams.append(make_stream("mag", ("mx", "my", "mz"), tcol(d), v * GAUSS_TO_UT, request,
                                           meta={"units": f"uT, {frame}", "topic": d.name}, notes=notes))
        if request.wants("baro"):
            d = _first(ulog, TOPICS["baro"])
            if d is None and px4_legacy.has_baro(combined):
                t_b, v_b, f_b, u_b = px4_legacy.combined_baro(combined, t0)
                streams.append(make_stream("baro", f_b, t_b, v_b, request, meta={"units": u_b, "topic":
                                           "sensor_combined (baro_alt_meter, an older layout)"}, notes=notes))
            elif d is None:
                missing.append("baro (vehicle_air_data or sensor_baro)")
            else:
                streams.append(_baro(d, tcol(d), request, notes))
        if request.wants("reference"):
            lpos = _first(ulog, ("vehicle_local_position",))
            att = _first(ulog, ("vehicle_attitude",))
            if lpos is None and att is None:
                missing.append("reference (vehicle_local_position, vehicle_attitude)")
            else:
                s, origin, initial = _reference(lpos, att, tcol, request, notes)
                if s is not None:
                    streams.append(s)
                    if origin is not None:   # fusion.importers.flight refers the reference to the first fix
                        s.meta["ekf_origin"] = f"{origin[0]:.9f} {origin[1]:.9f} {origin[2]:.3f}"
                if initial is not None:   # the first valid attitude, whenever the position becomes valid
                    streams.append(Stream("initial_attitude", ("qw", "qx", "qy", "qz"), np.array([initial[0]]),
                                          np.asarray(initial[1], float)[None, :], (F32,) * 4,
                                          {"source": "the first valid vehicle_attitude (body FRD to NED), for a "
                                           "config that starts in flight"}))
        _field_from_reference(streams, _first(ulog, ("vehicle_attitude",)) if request.wants("mag") else None, tcol)
        texts = [((int(m.timestamp) - t0) / 1e6, m.message) for m in ulog.logged_messages]
        for t, text in sorted(texts + px4_events(_first(ulog, ("vehicle_status",)), tcol), key=lambda m: m[0]):
            if (request.start is None or t >= request.start) and (request.end is None or t <= request.end):
                log.messages.append((t, text))
        _check_requested(path, request, missing, notes)
        to_header(streams, log.meta)
        log.streams = streams
        return log


def _field_from_reference(streams: list[Stream], att, tcol) -> None:
    """``# mag earth_field_ned``: the magnetometer's mean field rotated to NED by the onboard attitude."""
    mag = next((s for s in streams if s.sensor == "mag" and len(s)), None)
    if mag is None or att is None or mag.meta.get("units", "").find("body") < 0:
        return
    f = earth_field_ned(mag.t, mag.values, tcol(att), _cols(att, [f"q[{i}]" for i in range(4)]))
    if f is not None:
        mag.meta["earth_field_ned"] = " ".join(f"{v:.3f}" for v in f)
        mag.meta["earth_field_source"] = "mean of the samples rotated to NED by vehicle_attitude (uT)"


def _software(info: dict) -> str:
    """``, software v1.11.2 dev (git 8583f1da)`` from ver_sw_release (0xAABBCCTT: major minor patch type) and ver_sw."""
    out = []
    rel = info.get("ver_sw_release")
    if isinstance(rel, int) and rel > 0:
        kind = {255: "", 192: " rc", 128: " beta", 64: " alpha", 0: " dev"}.get(rel & 0xFF, "")
        out.append(f"v{(rel >> 24) & 0xFF}.{(rel >> 16) & 0xFF}.{(rel >> 8) & 0xFF}{kind}")
    if info.get("ver_sw"):
        out.append(f"(git {str(info['ver_sw'])[:8]})")
    return (", software " + " ".join(out)) if out else ""


def _check_requested(path: str, request: ImportRequest, missing: list[str], notes: list[str]) -> None:
    if not missing:
        return
    if request.sensors is not None:
        raise InputError(f"{path}: no data for {', '.join(missing)}")
    notes.append("not in the log: " + ", ".join(missing))


def _parse(path: str, request: ImportRequest):
    from pyulog import ULog
    from pyulog.core import ULogException

    topics = sorted({t for s, ts in TOPICS.items() if request.wants(s) for t in ts}
                    | ({"vehicle_attitude"} if request.wants("mag") else set())    # the field in NED (mag header)
                    | ({"sensor_combined"} if request.wants("mag") or request.wants("baro") else set())  # older layout
                    | {"vehicle_status"})   # arming, mode, failsafe (fusion.importers.flight_events)
    try:
        with open(path, "rb") as raw:
            fh = _Reader(raw)
            with silenced() as chatter:
                ulog = ULog(fh, topics)
            size = os.fstat(raw.fileno()).st_size
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except ULogException as exc:
        raise InputError(f"{path}: not a readable ULog file: {exc}") from None
    except Exception as exc:  # pyulog raises plain errors (struct, index, unicode) on damaged definitions
        raise InputError(f"{path}: damaged ULog file ({type(exc).__name__}: {exc})") from None
    if fh.cut_at is not None and not request.allow_partial:
        raise InputError(f"{path}: truncated: its last message is cut short by the end of the file (byte {size}); "
                         "pass --partial to import what comes before it")
    if ulog.file_corruption and not request.allow_partial:
        said = " ".join(chatter.getvalue().split())[:200]
        raise InputError(f"{path}: corrupt ULog data ({said or 'pyulog found invalid messages'}); pass --partial "
                         "to import the messages pyulog could read")
    said = []
    if fh.cut_at is not None:
        said.append(f"truncated: the last message is cut short by the end of the file at byte {size}; the "
                    "messages before it imported (--partial)")
    if ulog.file_corruption:
        chatter_text = " ".join(chatter.getvalue().split())[:200]
        said.append(f"corrupt ULog data ({chatter_text or 'pyulog found invalid messages'}): the messages pyulog "
                    "could read imported (--partial)")
    ulog.fusion_partial = "; ".join(said)
    if not any(len(d.data.get("timestamp", ())) for d in ulog.data_list):
        raise InputError(f"{path}: no data messages of {', '.join(topics)} (is the log empty or cut in its header?)")
    return ulog


def _gps(d, t: np.ndarray, request: ImportRequest, notes: list[str]) -> Stream:
    data = d.data
    if "lat" in data:
        lat, lon = np.asarray(data["lat"], float) / 1e7, np.asarray(data["lon"], float) / 1e7
        alt, fmt, layout = np.asarray(data["alt"], float) / 1e3, LATLON_E7, "lat/lon 1e-7 deg, alt mm"
    elif "latitude_deg" in data:
        lat, lon = np.asarray(data["latitude_deg"], float), np.asarray(data["longitude_deg"], float)
        alt, fmt, layout = np.asarray(data["altitude_msl_m"], float), LATLON_F, "lat/lon deg, alt m"
    else:
        raise InputError(f"{d.name}: neither lat/lon nor latitude_deg/longitude_deg fields")
    fields = ["lat", "lon", "alt"]
    cols = [lat, lon, alt]
    fmts = [fmt, fmt, ".3f"]
    vel_ok = None     # per sample, when the receiver flags some velocities invalid (and others valid)
    if all(f"vel_{a}_m_s" in data for a in "ned"):
        if "vel_ned_valid" in data and not np.any(np.asarray(data["vel_ned_valid"])):
            notes.append(f"gps: {d.name} never flags its velocity valid: no vn ve vd")
        else:
            fields += ["vn", "ve", "vd"]
            cols += [np.asarray(data[f"vel_{a}_m_s"], float) for a in "ned"]
            fmts += [F32] * 3
            if "vel_ned_valid" in data and not np.all(np.asarray(data["vel_ned_valid"])):
                vel_ok = np.asarray(data["vel_ned_valid"]) != 0
    for name, src in (("hacc", "eph"), ("vacc", "epv"), ("hdop", "hdop")):
        if src in data:
            fields.append(name)
            cols.append(np.asarray(data[src], float))
            fmts.append(F32)
    for name, src in (("fix", "fix_type"), ("nsat", "satellites_used")):
        if src in data:
            fields.append(name)
            cols.append(np.asarray(data[src], float))
            fmts.append("d")
    fix = np.asarray(data.get("fix_type", np.full(len(t), 3)), int)
    ok = fix >= 2
    if np.any(~ok):
        notes.append(f"gps: {int(np.sum(~ok))} sample(s) without a fix (fix_type < 2) dropped")
    if "alt_ellipsoid" in data or "altitude_ellipsoid_m" in data:   # the geoid's height above the ellipsoid
        ell = (np.asarray(data["alt_ellipsoid"], float) / 1e3 if "alt_ellipsoid" in data
               else np.asarray(data["altitude_ellipsoid_m"], float))
        fields.append("geoid")
        cols.append(ell - alt)
        fmts.append(".3f")
    if vel_ok is not None and len(fields) == 11 and "hacc" in fields:
        # the 13-value layout (gps_decoder.LAYOUTS): the per-sample flag after the geoid (0: not logged)
        fields.append("geoid")
        cols.append(np.zeros(len(t)))
        fmts.append(".3f")
    if vel_ok is not None and len(fields) == 12:
        fields.append("vok")
        cols.append(vel_ok.astype(float))
        fmts.append("d")
        notes.append(f"gps: {int(np.sum(~vel_ok[ok]))} of {int(np.sum(ok))} fix(es) with the velocity flagged "
                     "invalid (vel_ned_valid 0): written with vok 0, fused as position only")
    units = "deg deg m(AMSL)" + (" m/s m/s m/s (NED)" if "vn" in fields else "") + \
            (" m m (eph epv)" if "hacc" in fields else "") + (" - (hdop)" if "hdop" in fields else "") + \
            " - - (fix type, satellites)" + (" m (geoid height above the WGS84 ellipsoid)" if "geoid" in fields else "")
    return make_stream("gps", tuple(fields), t[ok], np.column_stack(cols)[ok], request, tuple(fmts),
                       meta={"units": units, "topic": f"{d.name} ({layout})"}, notes=notes)


def _baro(d, t: np.ndarray, request: ImportRequest, notes: list[str]) -> Stream:
    data = d.data
    if d.name == "vehicle_air_data":
        fields, names = ("alt", "pressure", "temp"), ["baro_alt_meter", "baro_pressure_pa"]
        names.append("baro_temp_celcius" if "baro_temp_celcius" in data else "baro_temp_celsius")
        v = _cols(d, [n for n in names if n in data])
        fields = tuple(f for f, n in zip(fields, names) if n in data)
        units = "m (pressure altitude) Pa degC"
    else:
        v = _cols(d, ["pressure", "temperature"])
        fields, units = ("pressure", "temp"), "Pa degC"
        if v.size and np.nanmedian(v[:, 0]) < 2000.0:   # older firmware logs mbar (~1013), newer Pa (~101325)
            v[:, 0] *= 100.0
            units += " (pressure logged in mbar, converted)"
    return make_stream("baro", fields, t, v, request, meta={"units": units, "topic": d.name}, notes=notes)
