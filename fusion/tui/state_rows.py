"""State elements for display: by name, with value, 1-sigma and unit; attitude as roll/pitch/yaw in degrees.

Angles are radians inside and degrees in the UI (DESIGN.md conventions): a quaternion block ``q`` is shown
as aerospace Euler angles (roll, pitch, yaw, deg) with 1-sigma from the linearised covariance
``J P_q J^T`` (J = d euler / d q, central differences); angle blocks and angular-rate blocks are converted
to deg and deg/s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fusion import quaternion
from fusion.api import Belief, StateLayout

# Units by block name (the conventions of the built-in process models; SI).
UNITS = {"p": "m", "v": "m/s", "a": "m/s^2", "ba": "m/s^2", "bw": "deg/s", "bg": "deg/s", "w": "deg/s",
         "clock": "s", "drift": "s/s"}
ANGULAR_RATES = {"bw", "bg", "w"}


@dataclass(frozen=True)
class Row:
    """One displayed element: ``key`` is the state element name (or ``roll``/``pitch``/``yaw``)."""

    key: str
    value: float
    sd: float
    unit: str


def state_rows(layout: StateLayout, belief: Belief) -> list[Row]:
    """Rows for every element of the state in layout order (a quaternion block becomes three angles)."""
    x = np.asarray(belief.x, dtype=float)
    sd = belief.sd
    rows: list[Row] = []
    for block in layout.blocks:
        sl = layout[block.name]
        if block.kind == "quaternion":
            P = belief.cov[sl, sl]
            angles, sigmas = euler_deg(x[sl], P)
            prefix = "" if block.name == "q" else f"{block.name}."
            for name, a, s in zip(("roll", "pitch", "yaw"), angles, sigmas):
                rows.append(Row(prefix + name, a, s, "deg"))
            continue
        scale, unit = 1.0, UNITS.get(block.name, "")
        if block.kind == "angle":
            scale, unit = 180.0 / math.pi, "deg"
        elif block.name in ANGULAR_RATES:
            scale = 180.0 / math.pi
        for name, v, s in zip(block.element_names(), x[sl], sd[sl]):
            rows.append(Row(name, float(v) * scale, float(s) * scale, unit))
    return rows


def euler_deg(q: np.ndarray, P_q: np.ndarray, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Roll, pitch, yaw (deg) of a quaternion (4,) and their 1-sigma (deg) from its covariance (4, 4)."""
    q = np.asarray(q, dtype=float)
    steps = eps * np.eye(4)
    e = quaternion.to_euler(np.vstack([q, q + steps, q - steps]))
    d = e[1:5] - e[5:9]
    d = (d + math.pi) % (2.0 * math.pi) - math.pi  # yaw/roll wrap at +-180 deg
    J = d.T / (2.0 * eps)  # (3, 4)
    var = np.einsum("ij,jk,ik->i", J, P_q, J)
    return np.degrees(e[0]), np.degrees(np.sqrt(np.clip(var, 0.0, None)))


def fmt_value(v: float) -> str:
    """A value for the table: 4 decimals (6 significant digits when large)."""
    if not math.isfinite(v):
        return str(v)
    return f"{v:.4f}" if abs(v) < 1e6 else f"{v:.6g}"


def fmt_sd(s: float) -> str:
    """A standard deviation: 3 significant digits."""
    return f"{s:.3g}" if math.isfinite(s) else str(s)
