"""How well an imported IMU stream can be dead-reckoned, written to the recording's header for ``fusion run``
(fusion.imu_coverage) to check.

Written as ``# imu coverage: ...`` (words) and ``# imu_coverage_fraction: F`` (a number, one per IMU).

- ``coverage_fraction``: the share of the stream's time the logged values stand for. PX4 logs in each
  ``sensor_combined`` row the gyro integrated over ``gyro_integral_dt`` (us); a log written at a low rate
  keeps a few-ms snapshot of a ~100 ms interval, and the rest of the motion is not in the log. The share
  is sum(min(integral_i, spacing_i)) / (t_last - t_first). Unknown (not written) when the log does not say.
- ``rotation_per_sample_deg``: the largest rotation between two samples, |gyro| x spacing (deg), and its
  99th percentile: an integration that holds a sample over a long interval is only as good as the rotation
  in it is small.
"""
from __future__ import annotations

import numpy as np


def imu_coverage(t: np.ndarray, gyro: np.ndarray, integral_dt: np.ndarray | None, source: str) -> dict[str, str]:
    """Header entries (see the module) of an IMU stream: times ``t`` (k,) s, body rates ``gyro`` (k, 3) rad/s,
    the interval each sample integrates ``integral_dt`` (k,) s or None (unknown), named ``source``."""
    t = np.asarray(t, float)
    if len(t) < 3:
        return {}
    dt = np.diff(t)
    spacing = float(np.median(dt))
    rate = np.linalg.norm(np.asarray(gyro, float), axis=1)
    turn = np.degrees(rate[:-1] * dt)        # each sample held over the interval to the next
    out = {"rotation_per_sample_deg": f"{float(np.max(turn)):.3g}",
           "rotation_per_sample": f"max {float(np.max(turn)):.3g} deg, 99th percentile "
                                  f"{float(np.percentile(turn, 99)):.3g} deg (|gyro| x spacing; median spacing "
                                  f"{spacing * 1e3:.3g} ms)"}
    if integral_dt is not None and len(integral_dt) == len(t):
        span = float(t[-1] - t[0])
        integ = np.asarray(integral_dt, float)[1:]
        ok = np.isfinite(integ) & (integ >= 0)
        if span > 0 and ok.any():
            covered = float(np.sum(np.minimum(integ[ok], dt[ok])) / np.sum(dt[ok]))
            out["coverage_fraction"] = f"{covered:.4g}"
            out["coverage"] = (f"{covered:.3g} of the time integrated ({source}: median "
                               f"{float(np.median(integ[ok])) * 1e3:.3g} ms for a median spacing of "
                               f"{spacing * 1e3:.3g} ms)")
    return out


#: The entries read by ``fusion run`` (fusion.imu_coverage), written as ``# SENSOR_KEY: value`` header lines.
MACHINE_KEYS = ("coverage_fraction", "rotation_per_sample_deg")


def to_header(streams, meta: dict[str, str]) -> None:
    """Move each stream's MACHINE_KEYS entries to the recording's ``meta`` as ``SENSOR_KEY`` (a plain
    ``# key: value`` line the log format's header reader keeps)."""
    for s in streams:
        for k in MACHINE_KEYS:
            if k in s.meta:
                meta[f"{s.sensor}_{k}"] = s.meta.pop(k)
