"""Every imported sensor on the IMU's clock: a stream whose time span does not overlap the IMU's was read
on another clock (a GPS time of week taken for the boot clock, a dataset's column in other units), and a
run would never put its messages beside the IMU's. Refused with the sensor and both spans, never written."""
from __future__ import annotations

from fusion.api import InputError, Stream


def check_one_clock(path: str, streams: list[Stream]) -> None:
    """InputError naming the first stream whose span (s) does not overlap the IMU's (``imu``, else the first
    ``imu*`` stream); nothing without an IMU."""
    imus = [s for s in streams if s.sensor.rstrip("0123456789") == "imu" and len(s)]
    if not imus:
        return
    imu = next((s for s in imus if s.sensor == "imu"), imus[0])
    c, d = float(imu.t.min()), float(imu.t.max())
    for s in streams:
        if s is imu or not len(s) or s.sensor == "initial_attitude":   # one line, at the reference's start
            continue
        a, b = float(s.t.min()), float(s.t.max())
        if b < c or a > d:
            raise InputError(f"{path}: {s.sensor}: its samples span t {a:.3f}..{b:.3f} s and the IMU's "
                             f"({imu.sensor}) t {c:.3f}..{d:.3f} s: they do not overlap, so they are not on one "
                             "clock (a GPS time of week read as the boot clock, or another unit); nothing written")
