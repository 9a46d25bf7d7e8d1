"""Shared helpers of the importers: time slicing, attitude conversions, unit factors.

Conventions (DESIGN.md): NED navigation frame, FRD body frame, Hamilton quaternions scalar first
``[w x y z]`` body-to-NED (C_b^n), SI units; GPS latitude/longitude in degrees, altitude in m above mean sea
level; magnetic field in uT (the unit of the project's recordings, ``# mag units: uT``).
"""
from __future__ import annotations

import contextlib
import io
import os
import sys
from typing import Iterator

import numpy as np

from fusion.api import ImportRequest, InputError, Stream

GAUSS_TO_UT = 100.0   # 1 G = 1e-4 T = 100 uT
DEG = np.pi / 180.0

# Column formats: 9 significant digits round-trip a float32 (the type of nearly every logged sensor value);
# latitude/longitude in 1e-7 deg (the integer layouts) are exact with 7 decimals, float degrees keep 9 (0.1 mm).
F32 = ".9g"
LATLON_E7 = ".7f"
LATLON_F = ".9f"


def in_span(t: np.ndarray, request: ImportRequest) -> np.ndarray:
    """Boolean mask of the times ``t`` (s) inside ``request.start``..``request.end`` (both inclusive)."""
    keep = np.isfinite(t)
    if request.start is not None:
        keep &= t >= request.start
    if request.end is not None:
        keep &= t <= request.end
    return keep


def finite_rows(values: np.ndarray) -> np.ndarray:
    """Boolean mask of the rows of ``values`` (k, m) whose numbers are all finite (the log format has no NaN)."""
    if values.dtype == object:
        return np.ones(len(values), bool)
    return np.all(np.isfinite(values), axis=1)


def make_stream(sensor: str, fields: tuple[str, ...], t: np.ndarray, values: np.ndarray, request: ImportRequest,
                formats: tuple[str, ...] | None = None, meta: dict[str, str] | None = None,
                notes: list[str] | None = None) -> Stream:
    """A Stream cut to the request's span, without non-finite rows (counted in ``notes``)."""
    t = np.asarray(t, float)
    values = np.asarray(values)
    if values.ndim == 1:
        values = values[:, None]
    if values.shape != (len(t), len(fields)):
        raise ValueError(f"{sensor}: values {values.shape} for {len(t)} times and {len(fields)} fields")
    span = in_span(t, request)
    fin = finite_rows(values)
    bad = int(np.sum(span & ~fin))
    if bad and notes is not None:
        notes.append(f"{sensor}: {bad} sample(s) with a non-finite value dropped")
    keep = span & fin
    return Stream(sensor, tuple(fields), t[keep], values[keep], formats, dict(meta or {}))


def quat_from_euler(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Quaternions (k, 4) ``[w x y z]`` body-to-NED from ZYX Euler angles (rad): C_b^n = Rz(yaw) Ry(pitch) Rx(roll)
    (the aerospace convention of PX4 and ArduPilot)."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    q = np.stack([cr * cp * cy + sr * sp * sy,
                  sr * cp * cy - cr * sp * sy,
                  cr * sp * cy + sr * cp * sy,
                  cr * cp * sy - sr * sp * cy], axis=-1)
    return canonical(q)


def canonical(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (k, 4) with w >= 0 (q and -q are the same attitude; one sign keeps columns smooth
    except near 180 deg)."""
    q = np.asarray(q, float)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    q = q / np.where(n > 0, n, 1.0)
    return np.where(q[..., :1] < 0, -q, q)


def slerp_to(t_q: np.ndarray, q: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Quaternions (k, 4) ``[w x y z]`` at times ``t`` by spherical interpolation of ``q`` (j, 4) given at the
    increasing times ``t_q``; held at the ends (no extrapolation)."""
    from scipy.spatial.transform import Rotation, Slerp

    t_q = np.asarray(t_q, float)
    order = np.argsort(t_q, kind="stable")
    t_q, q = t_q[order], np.asarray(q, float)[order]
    keep = np.concatenate([[True], np.diff(t_q) > 0])   # Slerp needs strictly increasing times
    t_q, q = t_q[keep], q[keep]
    if len(t_q) == 1:
        return np.repeat(q, len(t), axis=0)
    rot = Rotation.from_quat(q[:, [1, 2, 3, 0]])
    out = Slerp(t_q, rot)(np.clip(t, t_q[0], t_q[-1])).as_quat()[:, [3, 0, 1, 2]]
    # the sign of the source sample before each time (q and -q are one attitude: keep the log's hemisphere)
    near = q[np.clip(np.searchsorted(t_q, t, side="right") - 1, 0, len(t_q) - 1)]
    return np.where(np.sum(out * near, axis=1, keepdims=True) < 0, -out, out)


def require(cond: bool, path: str, what: str) -> None:
    """Raise InputError ``path: what`` unless ``cond``."""
    if not cond:
        raise InputError(f"{path}: {what}")


@contextlib.contextmanager
def silenced() -> Iterator[io.StringIO]:
    """Swallow what a reader library prints (pyulog and pymavlink print warnings, pymavlink's C indexer
    writes to the process's own stdout/stderr): Python-level text is kept in the yielded buffer, C-level
    text goes to /dev/null, so the command's one error line stays the only line."""
    said = io.StringIO()
    saved = []
    try:
        for fd, stream in ((1, sys.stdout), (2, sys.stderr)):
            try:
                stream.flush()
                saved.append((fd, os.dup(fd)))
            except (OSError, ValueError, AttributeError):
                continue
        null = os.open(os.devnull, os.O_WRONLY)
        try:
            for fd, _ in saved:
                os.dup2(null, fd)
        finally:
            os.close(null)
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            yield said
    finally:
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)


def earth_field_ned(t_mag: np.ndarray, m_body: np.ndarray, t_q: np.ndarray, q: np.ndarray) -> np.ndarray | None:
    """The Earth's field in NED (3,), in the units of ``m_body`` (k, 3): the mean of the body-frame samples
    rotated by the attitude ``q`` (j, 4) ``[w x y z]`` body-to-NED at their times (slerp), the onboard
    estimator's own view of the field (for configs: ``# mag earth_field_ned``). None without samples."""
    from fusion.quaternion import rotate

    if len(t_mag) == 0 or len(t_q) == 0:
        return None
    hold = float(np.median(np.diff(np.sort(t_q)))) if len(t_q) > 1 else 0.0   # one attitude period past the ends
    inside = (t_mag >= np.min(t_q) - hold) & (t_mag <= np.max(t_q) + hold)
    if not inside.any():
        return None
    qi = slerp_to(t_q, q, t_mag[inside])
    return np.mean(rotate(qi, m_body[inside]), axis=0)
