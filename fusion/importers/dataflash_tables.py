"""Reading ArduPilot DataFlash logs as column tables, for the ``dataflash`` importer.

pymavlink builds the index (the offset of every message, by type: its C indexer when built, else Python);
the columns are then read straight from the file's bytes at those offsets with numpy (a message type's
layout is its FMT record's format string), so only the requested types' bytes are touched and a time slice
reads only its span. The integrity of the file (a last message cut by the end, bytes that belong to no
message) is read from the same index.
"""
from __future__ import annotations

import numpy as np

from fusion.api import ImportRequest, InputError
from fusion.importers.common import silenced

# numbered instances and the EKF generations share the layout and units of one base message
_BASE = {"IMU2": "IMU", "IMU3": "IMU", "GPS2": "GPS", "GPA2": "GPA", "MAG2": "MAG", "MAG3": "MAG", "BAR2": "BARO",
         "BAR3": "BARO", "XKF1": "EKF", "NKF1": "EKF", "EKF1": "EKF"}


def open_log(path: str, request: ImportRequest):
    """pymavlink's reader of ``path``, its index built; InputError for a file that is not a DataFlash log,
    and for a truncated or corrupt one unless ``request.allow_partial``."""
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
    stop = _resync(reader)
    cut, gap, first_gap = _integrity(reader)
    why = (f": a message of unknown type 0x{stop[1]:02x}, where pymavlink's index stops"
           if stop is not None and stop[0] == first_gap else "")
    reader.fusion_cut = cut
    reader.fusion_damage = (f"corrupt: {gap} byte(s) belong to no message (the first at byte {first_gap}{why})"
                            if gap else None)   # said by the importer under --partial
    if not request.allow_partial:
        if cut is not None:
            raise InputError(f"{path}: truncated: the last message, at byte {cut}, is cut short by the end of the "
                             f"file at byte {reader.data_len}; pass --partial to import what comes before it")
        if gap:
            raise InputError(f"{path}: {reader.fusion_damage}; pass --partial to import the messages pymavlink "
                             "could read")
    return reader


def _resync(reader) -> tuple[int, int] | None:
    """Index the messages after the point where pymavlink's indexer stopped, if it stopped early.

    Both of pymavlink's indexers (C and Python) end the index at a message of an unknown type (a damaged
    type byte), without a word to the caller, so all that follows would be lost; its reader
    (``recv_match``) resyncs instead ("Skipped N bad bytes"), and so does this: from the stop, the next
    header ``A3 95`` of a known type whose message is followed by another header (or the end of the
    file), then message by message, resyncing again at each damaged one. FMT records met on the way are
    parsed, as pymavlink's indexer does. The offsets found are added to ``reader.offsets``; the bytes
    skipped are then gaps for ``_integrity``. Returns (offset, type byte) of the stop, or None when the
    index covered the file (or what follows it holds no message: end-of-file padding, which pymavlink
    ignores too)."""
    from pymavlink.DFReader import DFFormat, null_term
    import struct

    fmts = reader.formats
    end = 0
    for mtype, o in enumerate(reader.offsets):
        if len(o) and mtype in fmts:
            end = max(end, int(max(o)) + fmts[mtype].len)
    data, n = reader.data_map, reader.data_len
    head = b"\xa3\x95"
    at = data.find(head, end) if n - end >= 3 else -1   # the stop (after bytes the indexer skipped, if any)
    if at < 0 or at + 3 > n:
        return None
    stop = (at, data[at + 2])
    found: list[tuple[int, int]] = []
    pos = at + 1
    synced = False
    fmt_type = 0x80
    while pos + 3 <= n:
        if not synced:
            j = data.find(head, pos)
            if j < 0:
                break
            f = fmts.get(data[j + 2])
            k = j + (f.len if f is not None else 0)
            if f is None or k > n or (k + 2 <= n and data[k:k + 2] != head):
                pos = j + 1
                continue
            pos, synced = j, True
        mtype = data[pos + 2] if data[pos:pos + 2] == head else None
        f = fmts.get(mtype) if mtype is not None else None
        if f is None or pos + f.len > n:
            synced = False
            pos += 1
            continue
        found.append((mtype, pos))
        if mtype == fmt_type:
            try:
                el = struct.unpack(f.msg_struct, data[pos + 3:pos + f.len])
                mf = DFFormat(el[0], null_term(el[2]), el[1], null_term(el[3]), null_term(el[4]),
                              oldfmt=fmts.get(el[0]))
                fmts[el[0]] = mf
                reader.name_to_id[mf.name] = mf.type
                reader.id_to_name[mf.type] = mf.name
            except (struct.error, ValueError, KeyError, IndexError):
                pass
        pos += f.len
    if not found:
        return None
    offsets = [list(o) for o in reader.offsets]
    for mtype, o in found:
        offsets[mtype].append(o)
    reader.offsets = offsets
    return stop


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


# GPS time beside the boot clock, by layout: (GPS week column, GPS time-of-week column in ms)
GPS_TIME = (("GWk", "GMS"), ("Week", "TimeMS"))


def boot_clock(columns: list[str] | tuple[str, ...]) -> tuple[str, float] | None:
    """(column, s per unit) of a message layout's boot clock, or None when it has none.

    ``TimeUS`` (us) wherever it is; else a message that carries GPS time beside the boot clock (older
    firmware's ``GPS``: ``Status,TimeMS,Week,...,T``, where ``TimeMS`` is the GPS time of week and ``T`` the
    boot clock) has its boot time in ``T`` (ms); else ``TimeMS`` (ms)."""
    cols = set(columns)
    if "TimeUS" in cols:
        return "TimeUS", 1e-6
    if "T" in cols and "TimeMS" in cols and ("Week" in cols or "GWk" in cols):
        return "T", 1e-3
    if "TimeMS" in cols:
        return "TimeMS", 1e-3
    return None
_NEEDED = {
    "IMU": ("I", "AccX", "AccY", "AccZ", "GyrX", "GyrY", "GyrZ"),
    "GPS": ("I", "Status", "GMS", "GWk", "Week", "TimeMS", "NSats", "HDop", "Lat", "Lng", "Alt", "Spd", "GCrs", "VZ"),
    "GPA": ("I", "HAcc", "VAcc"), "MAG": ("I", "MagX", "MagY", "MagZ"), "BARO": ("I", "Alt", "Press", "Temp"),
    "ATT": ("Roll", "Pitch", "Yaw"), "EKF": ("C", "Roll", "Pitch", "Yaw", "VN", "VE", "VD", "PN", "PE", "PD"),
    "ORGN": ("Type", "Lat", "Lng", "Alt"), "FMTU": ("FmtType", "UnitIds", "MultIds"), "UNIT": ("Id", "Label"),
    "MULT": ("Id", "Mult"), "VER": ("FWS",), "MSG": ("Message",),
    "EV": ("Id",), "MODE": ("Mode", "ModeNum"), "ERR": ("Subsys", "ECode"),
}
# DataFlash format characters -> numpy dtypes (pymavlink's FORMAT_TO_STRUCT, little endian, packed)
_DTYPE = {"b": "<i1", "B": "<u1", "M": "<u1", "h": "<i2", "H": "<u2", "c": "<i2", "C": "<u2", "i": "<i4",
          "I": "<u4", "e": "<i4", "E": "<u4", "L": "<i4", "f": "<f4", "d": "<f8", "g": "<f2", "q": "<i8",
          "Q": "<u8", "n": "S4", "N": "S16", "Z": "S64", "a": "S64"}


# ArduPilot logs at most 3 IMUs, compasses, barometers (INS_MAX_INSTANCES, COMPASS_MAX_INSTANCES,
# BARO_MAX_INSTANCES) and 2 GPS + a blended one; a larger instance number is a damaged message
_MAX_INSTANCES = {"IMU": 3, "MAG": 3, "BARO": 3, "GPS": 3, "GPA": 3}
MAX_BOOT_S = 1e8   # a boot-clock time beyond ~3 years of uptime is a damaged message


def _absurd(t: np.ndarray) -> np.ndarray:
    """Mask of the times (s, file order) that are damaged: non-finite, beyond MAX_BOOT_S, or an isolated
    outlier (far from both neighbours, which agree with each other; "far" is 1 s or 100 median periods)."""
    bad = ~np.isfinite(t) | (t > MAX_BOOT_S)
    g = np.flatnonzero(~bad)
    if g.size >= 3:
        tg = t[g]
        jump = max(1.0, 100.0 * float(np.median(np.abs(np.diff(tg)))))
        prev, nxt, span = tg[1:-1] - tg[:-2], tg[2:] - tg[1:-1], tg[2:] - tg[:-2]
        bad[g[1:-1][(np.abs(prev) > jump) & (np.abs(nxt) > jump) & (np.abs(span) <= jump)]] = True
    return bad


def _table(reader, name: str, request: ImportRequest | None, notes: list[str] | None = None,
           jumps: list | None = None) -> dict[str, np.ndarray] | None:
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

    clock = boot_clock(fmt.columns)
    tcol = clock[0] if clock is not None else None
    out: dict[str, np.ndarray] = {}
    if clock is not None:
        t = read(clock[0], offs) * clock[1]
        if request is not None and offs.size:
            offs, t = _sane(buf, fmt, name, offs, t, read if "I" in where else None, notes, jumps)
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
        if col in where and col != tcol:
            out[col] = read(col, offs)
    for week, tow in GPS_TIME[1:]:   # an older layout's GPS time under the names of the newer one
        if week in out and tow in out and "GWk" not in out:
            out["GWk"], out["GMS"] = out.pop(week), out.pop(tow)
    out["_n"] = np.array(len(offs))
    return out


def _sane(buf, fmt, name: str, offs: np.ndarray, t: np.ndarray, read_col, notes, jumps):
    """Drop the messages of one type that are damaged although their bytes parse (an absurd time or instance
    number: a bit flip that left a valid header), and exact copies of earlier ones (a log concatenated with
    itself, only looked for when the clock goes back), the absurd ones said in ``notes``; a clock that goes
    back is recorded in ``jumps`` (offset, from s, to s, type, repeats dropped) for one note of collect's."""
    bad = _absurd(t)
    base = _BASE.get(name, name)
    inst = None
    if read_col is not None and base in _MAX_INSTANCES:
        inst = read_col("I", offs)
        bad |= inst >= _MAX_INSTANCES[base]
    if bad.any() and notes is not None:
        idx = np.flatnonzero(bad)
        said = "; ".join(f"byte {int(offs[i])} (t {t[i]:.6g} s" + (f", instance {int(inst[i])}" if inst is not None
                                                                 else "") + ")" for i in idx[:3])
        notes.append(f"{name}: {idx.size} message(s) with an absurd time or instance number skipped as corrupt: "
                     f"{said}{' ...' if idx.size > 3 else ''}")
    offs, t = offs[~bad], t[~bad]
    if t.size < 2:
        return offs, t
    back = np.flatnonzero(np.diff(t) < -1.0)
    if back.size:
        i = int(back[0])
        raw = buf[offs[:, None] + np.arange(fmt.len)]
        _, first = np.unique(np.ascontiguousarray(raw).view(np.dtype((np.void, fmt.len))).ravel(), return_index=True)
        if jumps is not None:
            jumps.append((int(offs[i + 1]), float(t[i]), float(t[i + 1]), name, int(offs.size - first.size)))
        if first.size < offs.size:
            keep = np.zeros(offs.size, bool)
            keep[np.sort(first)] = True
            offs, t = offs[keep], t[keep]
    return offs, t


FORMAT_MULT = {"c": 0.01, "C": 0.01, "e": 0.01, "E": 0.01, "L": 1e-7}   # pymavlink's FORMAT_TO_STRUCT


def collect(reader, path: str, types: list[str], request: ImportRequest, notes: list[str] | None = None):
    """Tables per message type (columns scaled by the format characters' multipliers), the units per
    (type, column) from FMTU/UNIT/MULT, and a vehicle description from VER or the first MSG. Damaged
    messages that parse (absurd time, instance) and exact repeats are dropped and said in ``notes``, as is a
    clock that goes back (two logs in one file, or a reboot)."""
    rows: dict[str, dict[str, np.ndarray]] = {}
    jumps: list[tuple[int, float, float, str, int]] = []
    for mt in types:
        tab = _table(reader, mt, request, notes, jumps)
        if tab is not None and int(tab["_n"]):
            rows[mt] = tab
    if jumps and notes is not None:
        at, t0, t1, _, _ = min(jumps)
        dup = [f"{name} {k}" for _, _, _, name, k in sorted(jumps, key=lambda j: j[3]) if k]
        notes.append(f"the log's clock goes back from {t0:.3f} s to {t1:.3f} s at byte {at} (the log twice in one "
                     "file, two logs, or a reboot): "
                     + (f"message(s) that repeat an earlier one byte for byte dropped ({', '.join(dup)}); " if dup
                        else "") + "the rest merged in time order (import each part from its own file)")
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
