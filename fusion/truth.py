"""The recording's truth (and reference) as a table: rows interpolated at any time (linear; quaternions by
slerp, fusion.quaternion; angles wrapped), with the gap rule of the class. Used by fusion.metrics for errors
and by the plots."""
from __future__ import annotations

import bisect
import math
from typing import Collection, Sequence

import numpy as np

from fusion import quaternion as quat
from fusion.api import Message

__all__ = ["Truth", "interpolate_row"]


# --------------------------------------------------------------------------- truth
def interpolate_row(tl: Sequence[float], rows, t: float, period: float, gap_periods: float,
                    quaternions: dict[str, list[int]], angle_cols: Sequence[int]) -> np.ndarray | None:
    """The row of ``rows`` (indexable by sample, each (m,)) at time ``t`` between the sorted sample times
    ``tl``: linear, quaternion column groups by slerp, angle columns wrapped to (-pi, pi]; the first or last
    row within half a ``period`` outside the span; None farther out, or inside a gap of more than
    ``gap_periods`` periods farther than half a period from both ends (used by Truth and TruthWindow)."""
    n = len(tl)
    if n == 0:
        return None
    half = 0.5 * period
    if t < tl[0]:
        row = rows[0].copy() if tl[0] - t <= half else None
    elif t >= tl[-1]:
        row = rows[n - 1].copy() if t - tl[-1] <= half else None
    else:
        i = bisect.bisect_right(tl, t)  # tl[i-1] <= t < tl[i]
        t0, t1 = tl[i - 1], tl[i]
        dt = t1 - t0
        if dt > gap_periods * period and min(t - t0, t1 - t) > half:
            return None
        f = (t - t0) / dt if dt > 0 else 1.0
        v0, v1 = rows[i - 1], rows[i]
        row = v0 + f * (v1 - v0)
        for cols in quaternions.values():
            row[cols] = quat.slerp_floats(v0[cols], v1[cols], f)
    if row is not None:
        for c in angle_cols:
            row[c] = (row[c] + math.pi) % (2.0 * math.pi) - math.pi
    return row


class Truth:
    """The true state over time, from the ``truth`` messages of a recording.

    ``t`` (N,) sorted times (s); ``values`` (N, m) rows by ``names`` (block-prefixed element names).
    Quaternions (names ``Pw Px Py Pz`` for a prefix P) are normalised and interpolated by slerp; angle
    columns declared with ``with_angles`` are unwrapped and interpolated along the shorter way.
    ``at(t)`` is None outside the truth span by more than half the median sample period, and inside a gap
    of more than ``GAP_PERIODS`` sample periods farther than half a period from both ends.
    """

    GAP_PERIODS = 5.0

    def __init__(self, t: np.ndarray, values: np.ndarray, names: Sequence[str], angles: Collection[str] = ()):
        t = np.asarray(t, dtype=float).reshape(-1)
        values = np.asarray(values, dtype=float).reshape(t.size, len(names))
        order = np.argsort(t, kind="stable")
        self.t, self.values = t[order], values[order].copy()
        self.names: tuple[str, ...] = tuple(names)
        self.index: dict[str, int] = {n: i for i, n in enumerate(self.names)}
        self.angles = frozenset(a for a in angles if a in self.index)
        self.quaternions: dict[str, list[int]] = {}
        for n in self.names:
            if n.endswith("w") and all(n[:-1] + a in self.index for a in "xyz"):
                cols = [self.index[n[:-1] + a] for a in "wxyz"]
                self.quaternions[n[:-1]] = cols
                q = self.values[:, cols]
                nrm = np.linalg.norm(q, axis=1, keepdims=True)
                self.values[:, cols] = np.divide(q, nrm, out=q.copy(), where=nrm > 0)
        self._angle_cols = [self.index[a] for a in sorted(self.angles)]
        for c in self._angle_cols:
            self.values[:, c] = np.unwrap(self.values[:, c])
        self._quat_cols = [c for cols in self.quaternions.values() for c in cols]
        self.period = float(np.median(np.diff(self.t))) if self.t.size > 1 else 0.0
        self._tlist = self.t.tolist()

    @classmethod
    def from_messages(cls, messages: Sequence[Message], names: Sequence[str],
                      angles: Collection[str] = ()) -> "Truth":
        """Truth from the messages of sensor ``truth`` (others are ignored) with the column ``names`` of
        ``# fields truth ...``. Messages whose values are not ``len(names)`` numbers are skipped and counted
        in ``skipped``."""
        names = tuple(names)
        if not names:
            raise ValueError("truth needs its field names ('# fields truth px py ...' in the log header)")
        ts, rows, skipped = [], [], 0
        for m in messages:
            if m.sensor != "truth":
                continue
            try:
                v = m.floats()
            except ValueError:
                skipped += 1
                continue
            if v.shape != (len(names),) or not np.all(np.isfinite(v)) or not math.isfinite(m.t):
                skipped += 1
                continue
            ts.append(m.t)
            rows.append(v)
        truth = cls(np.array(ts), np.array(rows).reshape(len(rows), len(names)), names, angles)
        truth.skipped = skipped
        return truth

    skipped: int = 0

    @classmethod
    def from_recording(cls, path, stream: str = "truth") -> "Truth":
        """The ``truth`` (or ``reference``) lines of a recording file, whole (for studies and plots of
        short recordings; a run itself streams them through fusion.truth_stream)."""
        from fusion.logformat import ParsedStream, iter_messages
        from fusion.sources.recording import open_lines

        parsed = ParsedStream()
        msgs = [m for m in iter_messages(open_lines(path), parsed)
                if isinstance(m, Message) and m.sensor == stream]
        names = parsed.header.fields.get(stream)
        if not names:
            raise ValueError(f"{path}: no '# fields {stream} ...' header")
        return cls.from_messages(msgs, names) if stream == "truth" else cls.from_messages(
            [m._replace(sensor="truth") for m in msgs], names)

    def with_angles(self, names: Collection[str]) -> "Truth":
        """A copy whose columns ``names`` (rad) are angles: unwrapped for interpolation, wrapped on output."""
        return Truth(self.t, self.values, self.names, set(self.angles) | set(names))

    def __len__(self) -> int:
        return int(self.t.size)

    def __repr__(self) -> str:
        span = f"{self.t[0]:.3f}..{self.t[-1]:.3f} s" if len(self) else "empty"
        return f"Truth({len(self)} samples, {span}, fields {' '.join(self.names)})"

    @property
    def span(self) -> tuple[float, float] | None:
        return (float(self.t[0]), float(self.t[-1])) if len(self) else None

    def row(self, t: float) -> np.ndarray | None:
        """The interpolated truth row (m,) at time ``t`` (s), in ``names`` order, or None (see class)."""
        return interpolate_row(self._tlist, self.values, t, self.period, self.GAP_PERIODS, self.quaternions,
                               self._angle_cols)

    def at(self, t: float) -> dict[str, float] | None:
        """``{name: value}`` of the truth at time ``t`` (s), or None where truth is not defined."""
        row = self.row(t)
        return None if row is None else dict(zip(self.names, row.tolist()))

    def sample(self, times: np.ndarray) -> np.ndarray:
        """Rows (k, m) at ``times`` (k,); NaN rows where truth is not defined (for plots)."""
        out = np.full((len(times), len(self.names)), np.nan)
        for k, t in enumerate(np.asarray(times, dtype=float).tolist()):
            r = self.row(t)
            if r is not None:
                out[k] = r
        return out


