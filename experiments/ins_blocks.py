"""NEES per block of the 22-state INS of paper 002 (configs/imu_gps_mag_ekf.yaml): position, velocity,
attitude, ba, bw, sa, sw apart, to say where a filtered or smoothed NEES departs from its dof; used by
experiments/smoother_seeds.py.

The attitude error is the body-frame rotation ``2 vec(q_true^-1 (x) q_est)`` (rad), its covariance the
quaternion block's mapped by the same linearisation (experiments/abps_smoothed.py, pose_blocks.py).

Frames: the filter's local NED frame has its origin at the mean of the static GPS fixes (paper 002 sec. 3.1,
the nmea decoder's ``origin_s``), the truth's at the scenario's ``origin``. The two differ by the mean's
error ``e`` (m, NED), common to every fix and invisible to the filter. ``frame_offset`` gives ``e`` from the
run summary's decoder origin; the position block is scored both in the filter's frame (truth - e: what
the filter estimates) and in the scenario's (as the summary's NEES).
"""
from __future__ import annotations

import numpy as np
import pymap3d

from fusion import quaternion as quat
from fusion.consistency import chi2_interval
from fusion.metrics import Truth

__all__ = ["BLOCKS", "frame_offset", "block_nees"]

BLOCKS = (("p", 3), ("v", 3), ("attitude", 3), ("ba", 3), ("bw", 3), ("sa", 3), ("sw", 3))
_TRUTH = {"p": ("px", "py", "pz"), "v": ("vx", "vy", "vz"), "ba": ("bax", "bay", "baz"),
          "bw": ("bwx", "bwy", "bwz"), "sa": ("sax", "say", "saz"), "sw": ("swx", "swy", "swz")}


def frame_offset(summary: dict, header_origin: tuple[float, float, float], sensor: str = "gps") -> np.ndarray:
    """e (3,) m: the filter's NED origin (the decoder's, from ``summary['info']``) in the scenario's NED
    frame about ``header_origin`` (lat deg, lon deg, alt m)."""
    o = summary["info"][sensor]["decoder"]["origin"]
    n, e, d = pymap3d.geodetic2ned(o["lat_deg"], o["lon_deg"], o["alt_m"], *header_origin)
    return np.array([float(n), float(e), float(d)])


def block_nees(estimates, truth: Truth, layout, offset: np.ndarray, t_min: float = 0.0) -> dict:
    """Mean NEES of each block of :data:`BLOCKS` over ``estimates`` after ``t_min`` s, in the filter's frame
    (truth position - ``offset``); ``all``: the 21-dof NEES, ``in95``: its fraction inside the per-sample
    95% chi-square interval, ``p_scenario``: the position block against the untranslated truth; ``bax`` ...
    ``swz``: each sensor-error element's mean squared error over its variance (1 if consistent)."""
    sums = {name: [] for name, _ in BLOCKS}
    total, p_sc, axes = [], [], []
    lo, hi = chi2_interval(21)
    for est in estimates:
        if est.t < t_min:
            continue
        tv = truth.at(est.t)
        if tv is None:
            continue
        x, P = est.belief.x, est.belief.cov
        iq = layout["q"]
        q = x[iq] / np.linalg.norm(x[iq])
        qt = np.array([tv["qw"], tv["qx"], tv["qy"], tv["qz"]])
        d = quat.multiply(quat.conjugate(qt), q)           # q_true^-1 (x) q_est: body-frame error rotation
        d = -d if d[0] < 0 else d
        w, a, b, c = q[0], -q[1], -q[2], -q[3]
        T = np.zeros((21, 22))
        errs, j = [], 0
        for name, k in BLOCKS:
            if name == "attitude":
                T[j:j + 3, iq] = 2.0 * np.array([[a, w, -c, b], [b, c, w, -a], [c, -b, a, w]])
                errs.append(2.0 * d[1:])
            else:
                T[j:j + k, layout[name]] = np.eye(k)
                tr = np.array([tv[n] for n in _TRUTH[name]])
                errs.append(x[layout[name]] - (tr - offset if name == "p" else tr))
            j += k
        E = np.concatenate(errs)
        C = T @ P @ T.T
        total.append(float(E @ np.linalg.solve(C, E)))
        j = 0
        for name, k in BLOCKS:
            sums[name].append(float(E[j:j + k] @ np.linalg.solve(C[j:j + k, j:j + k], E[j:j + k])))
            j += k
        axes.append(E[9:21] ** 2 / np.diag(C)[9:21])
        e_sc = E[0:3] - offset
        p_sc.append(float(e_sc @ np.linalg.solve(C[0:3, 0:3], e_sc)))
    tot = np.array(total)
    out = {name: float(np.mean(v)) for name, v in sums.items()}
    ax = np.mean(axes, axis=0)
    out.update({"all": float(tot.mean()), "in95": float(np.mean((tot >= lo) & (tot <= hi))),
                "p_scenario": float(np.mean(p_sc))})
    out.update({f"{b}{c}": float(v) for (b, c), v in zip(((b, c) for b in ("ba", "bw", "sa", "sw") for c in "xyz"), ax)})
    return out
