"""A smooth ground path through waypoints, parameterised by horizontal arc length ``s`` (m).

The path follows the straight legs of the waypoint polyline exactly and rounds each corner with a
turn whose heading follows a quintic smoothstep, ``psi(s) = psi_in + dpsi * H((s - s0) / l)``, so the
curvature ``kappa = dpsi * H'/l`` is continuous (zero at both ends of the turn) and peaks at
``1/radius`` in the middle: ``l = 15/8 * |dpsi| * radius``. The turn starts a distance ``d`` before the
corner and ends ``d`` after it (``d`` from the turn's own geometry), so a vehicle moving along the path has
a continuous acceleration. Height (NED ``z``, down) follows a smoothstep between the waypoints' stations.

Frame: ``x`` north, ``y`` east, ``z`` down (NED); heading ``psi`` from north towards east (rad).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fusion.simulate.profiles import H_PRIME_MAX, smoothstep, smoothstep_d1, smoothstep_d2

_GL_X, _GL_W = np.polynomial.legendre.leggauss(24)
_GL_X = 0.5 * (_GL_X + 1.0)  # nodes on [0, 1]
_GL_W = 0.5 * _GL_W


class PathError(ValueError):
    """The waypoints cannot make a path (the message names the waypoint)."""


@dataclass(frozen=True)
class _Turn:
    s0: float      # arc length where the turn starts
    length: float  # arc length of the turn
    psi0: float    # heading at its start
    dpsi: float    # signed heading change
    start: np.ndarray  # (2,) point where it starts


def _turn_offset(psi0: float, dpsi: float, length: float) -> tuple[np.ndarray, float]:
    """Displacement (2,) over a turn starting at heading psi0, and the distance d from the turn's ends to
    the intersection of its entry and exit tangent lines (equal on both sides by symmetry)."""
    psi = psi0 + dpsi * smoothstep(_GL_X)
    disp = length * np.array([np.sum(_GL_W * np.cos(psi)), np.sum(_GL_W * np.sin(psi))])
    e_sum = np.array([np.cos(psi0) + np.cos(psi0 + dpsi), np.sin(psi0) + np.sin(psi0 + dpsi)])
    d = float(disp @ e_sum / (e_sum @ e_sum))
    return disp, d


class WaypointPath:
    """Smooth path through 2-D waypoints (N, 2) with a turning radius per corner (N,) and heights (N,)."""

    def __init__(self, points: np.ndarray, radii: np.ndarray, heights: np.ndarray | None = None):
        pts = np.asarray(points, float)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
            raise PathError(f"need at least 2 waypoints of 2 coordinates, got shape {pts.shape}")
        legs = np.diff(pts, axis=0)
        leg_len = np.hypot(legs[:, 0], legs[:, 1])
        bad = np.flatnonzero(leg_len < 1e-9)
        if bad.size:
            raise PathError(f"waypoints {bad[0]} and {bad[0] + 1} coincide")
        heading = np.arctan2(legs[:, 1], legs[:, 0])
        n = len(pts)
        radii = np.broadcast_to(np.asarray(radii, float), (n,))
        self.points = pts
        # corner i (1..n-2): turn of dpsi_i, length l_i, tangent offset d_i
        d = np.zeros(n)
        turns_geo: dict[int, tuple[float, float, np.ndarray]] = {}
        for i in range(1, n - 1):
            dpsi = float((heading[i] - heading[i - 1] + np.pi) % (2 * np.pi) - np.pi)
            if abs(dpsi) < 1e-12:
                continue
            if abs(dpsi) > np.deg2rad(175.0):
                raise PathError(f"waypoint {i}: the route turns back on itself ({np.rad2deg(dpsi):.1f} deg); "
                                "add a waypoint to make the U-turn out of two corners")
            length = H_PRIME_MAX * abs(dpsi) * float(radii[i])
            if length <= 0:
                continue
            disp, d[i] = _turn_offset(float(heading[i - 1]), dpsi, length)
            turns_geo[i] = (dpsi, length, disp)
        for k in range(n - 1):
            if d[k] + d[k + 1] > leg_len[k] + 1e-9:
                raise PathError(f"waypoints {k}-{k + 1}: leg of {leg_len[k]:.3f} m is too short for the turns at its "
                                f"ends (they need {d[k] + d[k + 1]:.3f} m); reduce the radius there")
        # lay out segments: straight legs and turns, with the arc length station of each waypoint
        turns: list[_Turn] = []
        stations = np.zeros(n)
        s = 0.0
        for k in range(n - 1):
            straight = leg_len[k] - d[k] - d[k + 1]
            s += straight
            if k + 1 in turns_geo:
                dpsi, length, disp = turns_geo[k + 1]
                start = pts[k + 1] - d[k + 1] * np.array([np.cos(heading[k]), np.sin(heading[k])])
                turns.append(_Turn(s, length, float(heading[k]), dpsi, start))
                stations[k + 1] = s + 0.5 * length
                s += length
            else:
                stations[k + 1] = s
        self.length = s
        self.stations = stations
        self._turns = turns
        self._leg_heading = heading
        self._turn_of: dict[int, int] = {}
        j = 0
        for i in range(1, n - 1):
            if i in turns_geo:
                self._turn_of[i] = j
                j += 1
        self.heights = np.zeros(n) if heights is None else np.asarray(heights, float)

    def turn_span(self, i: int) -> tuple[float, float]:
        """Stations (m) where the turn at waypoint i starts and ends (both its station when it has none)."""
        j = self._turn_of.get(i)
        if j is None:
            return float(self.stations[i]), float(self.stations[i])
        tr = self._turns[j]
        return tr.s0, tr.s0 + tr.length

    # ------------------------------------------------------------------ horizontal geometry
    def _locate(self, s: np.ndarray):
        """For each s: leg index k, whether in a turn (index into self._turns or -1)."""
        s = np.clip(np.asarray(s, float), 0.0, self.length)
        turn_idx = np.full(s.shape, -1)
        for j, tr in enumerate(self._turns):
            turn_idx[(s >= tr.s0) & (s < tr.s0 + tr.length)] = j
        return s, turn_idx

    def heading(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Heading psi (rad), curvature kappa = dpsi/ds (1/m) and dkappa/ds at arc lengths s."""
        s, ti = self._locate(s)
        psi = np.empty(s.shape)
        kap = np.zeros(s.shape)
        dkap = np.zeros(s.shape)
        # heading on straight parts: heading of the leg the point lies on
        leg_start = self.stations.copy()
        k = np.clip(np.searchsorted(leg_start, s, side="right") - 1, 0, len(self._leg_heading) - 1)
        psi[:] = self._leg_heading[k]
        # after the middle of a corner turn we are on the next leg already (stations are turn middles);
        # turns are handled explicitly below
        for j, tr in enumerate(self._turns):
            m = ti == j
            if not m.any():
                continue
            x = (s[m] - tr.s0) / tr.length
            psi[m] = tr.psi0 + tr.dpsi * smoothstep(x)
            kap[m] = tr.dpsi * smoothstep_d1(x) / tr.length
            dkap[m] = tr.dpsi * smoothstep_d2(x) / tr.length ** 2
        return psi, kap, dkap

    def position(self, s: np.ndarray) -> np.ndarray:
        """Horizontal position (..., 2) at arc lengths s (exact on straight parts, 24-point Gauss-Legendre
        quadrature inside turns: error below 1e-12 m)."""
        s, ti = self._locate(s)
        out = np.empty(s.shape + (2,))
        # straight parts: from the end of the previous turn (or the first waypoint) along the leg heading
        anchors_s = [0.0]
        anchors_p = [self.points[0]]
        anchors_psi = [self._leg_heading[0]]
        for tr in self._turns:
            disp, _ = _turn_offset(tr.psi0, tr.dpsi, tr.length)
            anchors_s.append(tr.s0 + tr.length)
            anchors_p.append(tr.start + disp)
            anchors_psi.append(tr.psi0 + tr.dpsi)
        anchors_s_arr = np.array(anchors_s)
        a = np.clip(np.searchsorted(anchors_s_arr, s, side="right") - 1, 0, len(anchors_s) - 1)
        ap = np.array(anchors_p)[a]
        apsi = np.array(anchors_psi)[a]
        ds = (s - anchors_s_arr[a])[..., None]
        out[:] = ap + ds * np.stack([np.cos(apsi), np.sin(apsi)], axis=-1)
        for j, tr in enumerate(self._turns):
            m = ti == j
            if not m.any():
                continue
            sig = s[m] - tr.s0                                     # (M,)
            nodes = sig[:, None] * _GL_X[None, :]                  # (M, 24)
            psi = tr.psi0 + tr.dpsi * smoothstep(nodes / tr.length)
            out[m] = tr.start + sig[:, None] * np.stack([np.cos(psi) @ _GL_W, np.sin(psi) @ _GL_W], axis=-1)
        return out

    # ------------------------------------------------------------------ vertical profile
    def height(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """z (m, down), dz/ds and d2z/ds2 at arc lengths s: smoothstep between waypoint stations."""
        s = np.clip(np.asarray(s, float), 0.0, self.length)
        st, zh = self.stations, self.heights
        k = np.clip(np.searchsorted(st, s, side="right") - 1, 0, len(st) - 2)
        span = st[k + 1] - st[k]
        dz = zh[k + 1] - zh[k]
        x = (s - st[k]) / span
        return zh[k] + dz * smoothstep(x), dz * smoothstep_d1(x) / span, dz * smoothstep_d2(x) / span ** 2
