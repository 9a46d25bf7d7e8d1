"""Write small ArduPilot DataFlash (.bin) logs for the tests: every message type declared by its own FMT
record (and units/multipliers by FMTU, UNIT and MULT records), as ArduPilot's AP_Logger writes them, so that
pymavlink reads them like a log from a vehicle. Message layouts follow ArduPilot's LogStructure.h."""
from __future__ import annotations

import struct

HEAD = b"\xa3\x95"
FMT_TYPE = 128
_STRUCT = {"a": "64s", "b": "b", "B": "B", "h": "h", "H": "H", "i": "i", "I": "I", "f": "f", "d": "d",
           "n": "4s", "N": "16s", "Z": "64s", "c": "h", "C": "H", "e": "i", "E": "I", "L": "i", "M": "b",
           "q": "q", "Q": "Q"}

# name: (format, columns, units, multipliers); units/multipliers as in ArduPilot 4.x
FORMATS = {
    "UNIT": ("QbZ", "TimeUS,Id,Label", None, None),
    "MULT": ("Qbd", "TimeUS,Id,Mult", None, None),
    "FMTU": ("QBNN", "TimeUS,FmtType,UnitIds,MultIds", None, None),
    "IMU": ("QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz",
            "s#EEEooo--O--zz", "F-000000-----00"),
    "GPS": ("QBBIHBcLLeffffB", "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U",
            "s#-s-S-DUmnhnh-", "F--C--BGGB0000-"),
    "MAG": ("QBhhhhhhhhhBI", "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S",
            "s#GGGGGGGGG-s", "F-CCCCCCCCC-F"),
    "BARO": ("QBfffcfIffBf", "TimeUS,I,Alt,AltAMSL,Press,Temp,CRt,SMS,Offset,GndTemp,H,CPress",
             "s#mmPOnsmO-P", "F-000B0C?0-0"),
    "ATT": ("QccccCCCCB", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw,AEKF",
            "sddddhhdh-", "FBBBBBBBB-"),
    "XKF1": ("QBccCfffffffccce", "TimeUS,C,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD,GX,GY,GZ,OH",
             "s#ddhnnnnmmmkkkm", "F-BBB0000000BBBB"),
    "ORGN": ("QBLLe", "TimeUS,Type,Lat,Lng,Alt", "s#DUm", "F-GGB"),
    "MSG": ("QZ", "TimeUS,Message", "s-", "F-"),
}
UNITS = {"s": "s", "E": "rad/s", "o": "m/s/s", "O": "degC", "z": "Hz", "S": "satellites", "D": "deglatitude",
         "U": "deglongitude", "m": "m", "n": "m/s", "h": "degheading", "G": "Gauss", "P": "Pa", "d": "deg",
         "k": "deg/s", "-": "", "#": "instance"}
MULTS = {"-": 0.0, "?": 1.0, "0": 1.0, "B": 1e-2, "C": 1e-3, "F": 1e-6, "G": 1e-7}


class DataflashWriter:
    """Builds a .bin in memory: ``declare`` the types (FMT + FMTU), then ``write(name, **values)``; values of
    c/C/e/E/L fields are given in their scaled units (deg, m, ...) and stored as ArduPilot stores them."""

    def __init__(self, units: bool = True):
        self.buf = bytearray()
        self.types: dict[str, tuple[int, str, list[str]]] = {}
        self._next = 64
        self.units = units
        self._fmt(FMT_TYPE, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")
        if units:
            for name in ("UNIT", "MULT", "FMTU"):
                self.declare(name, with_units=False)
            for k, v in UNITS.items():
                self.write("UNIT", TimeUS=0, Id=ord(k), Label=v)
            for k, v in MULTS.items():
                self.write("MULT", TimeUS=0, Id=ord(k), Mult=v)

    def _fmt(self, mtype: int, name: str, fmt: str, cols: str) -> None:
        length = 3 + struct.calcsize("<" + "".join(_STRUCT[c] for c in fmt))
        body = struct.pack("<BB4s16s64s", mtype, length, name.encode(), fmt.encode(), cols.encode())
        self.buf += HEAD + bytes([FMT_TYPE]) + body
        self.types[name] = (mtype, fmt, cols.split(","))

    def declare(self, name: str, fmt: str | None = None, cols: str | None = None, with_units: bool = True,
                units: str | None = None, mults: str | None = None) -> None:
        f, c, u, m = FORMATS[name] if fmt is None else (fmt, cols, None, None)
        u, m = units or u, mults or m
        self._next += 1
        self._fmt(self._next, name, f, c)  # type: ignore[arg-type]
        if with_units and self.units and u is not None:
            self.write("FMTU", TimeUS=0, FmtType=self._next, UnitIds=u, MultIds=m)

    def write(self, name: str, **values) -> None:
        mtype, fmt, cols = self.types[name]
        packed = []
        for c, col in zip(fmt, cols):
            v = values.get(col, 0)
            if c in "cCeE":
                v = int(round(v * 100))
            elif c == "L":
                v = int(round(v * 1e7))
            elif c in "nNZa":
                v = v.encode() if isinstance(v, str) else v
            elif c in "bBhHiIMqQ":
                v = int(v)
            packed.append(v)
        self.buf += HEAD + bytes([mtype]) + struct.pack("<" + "".join(_STRUCT[c] for c in fmt), *packed)

    def save(self, path) -> None:
        with open(path, "wb") as fh:
            fh.write(bytes(self.buf))
