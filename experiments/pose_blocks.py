"""Position and attitude NEES apart, for the pose filter of paper 003 (configs/ultrasonic_3d_pose.yaml):
used by experiments/smoother_seeds.py to say which block makes the smoothed NEES exceed its dof.

The attitude error is the body-frame rotation ``2 vec(q_true^-1 (x) q_est)`` (rad), its covariance the
quaternion block's mapped by the same linearisation (as experiments/abps_smoothed.py does for the INS).
"""
from __future__ import annotations

import numpy as np

from fusion import quaternion as quat
from fusion.metrics import Truth

__all__ = ["block_nees"]


def block_nees(estimates, truth: Truth, layout) -> dict:
    """Mean NEES of the position block (3 dof) and of the attitude (3 dof) over ``estimates``."""
    ip = layout["p"]
    iq = layout["q"] if "q" in layout else None
    pos, att = [], []
    for est in estimates:
        tv = truth.at(est.t)
        if tv is None:
            continue
        x, P = est.belief.x, est.belief.cov
        e = x[ip] - np.array([tv["px"], tv["py"], tv["pz"]])
        pos.append(float(e @ np.linalg.solve(P[ip, ip], e)))
        if iq is None:
            continue
        q = x[iq] / np.linalg.norm(x[iq])
        qt = np.array([tv["qw"], tv["qx"], tv["qy"], tv["qz"]])
        d = quat.multiply(quat.conjugate(qt), q)
        d = -d if d[0] < 0 else d
        w, a, b, c = q[0], -q[1], -q[2], -q[3]
        T = 2.0 * np.array([[a, w, -c, b], [b, c, w, -a], [c, -b, a, w]])
        ea = 2.0 * d[1:]
        att.append(float(ea @ np.linalg.solve(T @ P[iq, iq] @ T.T, ea)))
    return {"p": float(np.mean(pos)), "attitude": float(np.mean(att)) if att else float("nan")}
