"""Write small PX4 ULog files for the tests (the layouts the shipped real log does not have: newer PX4's
float ``sensor_gps``, ``sensor_mag`` without ``vehicle_magnetometer``, ``sensor_baro`` in mbar), following
the ULog file format (docs.px4.io "ULog File Format"): a 16-byte header, a flag-bits message, format ('F'),
info ('I'), then subscriptions ('A') and data ('D')."""
from __future__ import annotations

import struct

_TYPES = {"uint64_t": "Q", "int64_t": "q", "uint32_t": "I", "int32_t": "i", "uint16_t": "H", "int16_t": "h",
          "uint8_t": "B", "int8_t": "b", "float": "f", "double": "d", "bool": "?", "char": "c"}


class UlogWriter:
    def __init__(self, start_us: int = 1_000_000):
        self.buf = bytearray(b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", start_us))
        self._msg(b"B", bytes(8) + bytes(8) + bytes(24))            # compat, incompat flags, appended offsets
        self.formats: dict[str, list[tuple[str, str]]] = {}
        self.ids: dict[tuple[str, int], int] = {}

    def _msg(self, kind: bytes, payload: bytes) -> None:
        self.buf += struct.pack("<HB", len(payload), kind[0]) + payload

    def info(self, key: str, value: str) -> None:
        k = f"char[{len(value)}] {key}".encode()
        self._msg(b"I", bytes([len(k)]) + k + value.encode())

    def topic(self, name: str, fields: list[tuple[str, str]]) -> None:
        """Declare a topic; ``fields`` (type, name) after the implicit ``uint64_t timestamp``."""
        fields = [("uint64_t", "timestamp"), *fields]
        self.formats[name] = fields
        self._msg(b"F", (name + ":" + "".join(f"{t} {n};" for t, n in fields)).encode())

    def subscribe(self, name: str, multi_id: int = 0) -> None:
        msg_id = len(self.ids)
        self.ids[(name, multi_id)] = msg_id
        self._msg(b"A", struct.pack("<BH", multi_id, msg_id) + name.encode())

    def data(self, name: str, multi_id: int = 0, **values) -> None:
        """One sample; an array field (``float[3] q``) takes a sequence."""
        fmt, flat = "<", []
        for t, n in self.formats[name]:
            if "[" in t:
                base, count = t[:-1].split("[")
                fmt += _TYPES[base] * int(count)
                flat += list(values.get(n, [0] * int(count)))
            else:
                fmt += _TYPES[t]
                flat.append(values.get(n, 0))
        body = struct.pack(fmt, *flat)
        self._msg(b"D", struct.pack("<H", self.ids[(name, multi_id)]) + body)

    def save(self, path) -> None:
        with open(path, "wb") as fh:
            fh.write(bytes(self.buf))
