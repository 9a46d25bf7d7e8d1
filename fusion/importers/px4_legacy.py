"""Older PX4 ``sensor_combined`` layouts (PX4 up to v1.6 or so), for the ``ulog`` importer.

Those logs carry the magnetometer and barometer inside ``sensor_combined`` (``magnetometer_ga[3]`` Gauss
body FRD, ``baro_alt_meter`` m, ``baro_temp_celcius`` degC; the oldest also ``baro_pres_mbar``), each with
its own ``*_timestamp_relative`` (us after the row's ``timestamp``; 0x7FFFFFFF: no sample), and the gyro as
``gyro_rad_s[3]`` before it became ``gyro_rad[3]``. A magnetometer or barometer sample is repeated in every
row until the next one: a new sample is a row whose own time or values changed.

The IMU's integration intervals (``gyro_integral_dt``, ``accelerometer_integral_dt``, us) say how much of
the time between two rows the logged values stand for (fusion.importers.coverage).
"""
from __future__ import annotations

import numpy as np

INVALID_RELATIVE = 0x7FFFFFFF   # PX4 RELATIVE_TIMESTAMP_INVALID


def gyro_field(data: dict) -> str | None:
    """``gyro_rad`` (newer) or ``gyro_rad_s`` (older) when the topic has it, else None."""
    return next((f for f in ("gyro_rad", "gyro_rad_s") if f"{f}[0]" in data), None)


def has_mag(d) -> bool:
    return d is not None and "magnetometer_ga[0]" in d.data


def has_baro(d) -> bool:
    return d is not None and "baro_alt_meter" in d.data


def _new_samples(d, t0: int, rel_name: str, cols: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(t s from the log's start, values (k, m)) of the rows that carry a new sample of a sub-sensor."""
    data = d.data
    ts = np.asarray(data["timestamp"], np.int64)
    v = np.column_stack([np.asarray(data[c], float) for c in cols])
    if rel_name in data:
        rel = np.asarray(data[rel_name], np.int64)
        ok = rel != INVALID_RELATIVE
        stamp = ts + np.where(ok, rel, 0)
    else:
        ok = np.ones(len(ts), bool)
        stamp = ts
    same_time = np.concatenate([[False], stamp[1:] == stamp[:-1]])
    same_vals = np.concatenate([[False], np.all(v[1:] == v[:-1], axis=1)])
    # a relative stamp says when the sample was taken: a new stamp is a new sample; without one, a change
    keep = ok & ~(same_time if rel_name in data else same_vals)
    return (stamp[keep] - t0) / 1e6, v[keep]


def combined_mag(d, t0: int) -> tuple[np.ndarray, np.ndarray]:
    """Magnetometer samples of an older ``sensor_combined``: (t s, field (k, 3) Gauss, body FRD)."""
    return _new_samples(d, t0, "magnetometer_timestamp_relative", [f"magnetometer_ga[{i}]" for i in range(3)])


def combined_baro(d, t0: int) -> tuple[np.ndarray, np.ndarray, tuple[str, ...], str]:
    """Barometer samples of an older ``sensor_combined``: (t s, values, field names, units)."""
    data = d.data
    cols, fields, units = ["baro_alt_meter"], ["alt"], ["m (pressure altitude)"]
    if "baro_pres_mbar" in data:
        cols.append("baro_pres_mbar")
        fields.append("pressure")
        units.append("Pa (logged in mbar, converted)")
    temp = next((c for c in ("baro_temp_celcius", "baro_temp_celsius") if c in data), None)
    if temp is not None:
        cols.append(temp)
        fields.append("temp")
        units.append("degC")
    t, v = _new_samples(d, t0, "baro_timestamp_relative", cols)
    if "pressure" in fields:
        v[:, fields.index("pressure")] *= 100.0
    return t, v, tuple(fields), " ".join(units)
