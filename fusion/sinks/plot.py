"""``--plot PATH.png``: trajectory vs truth (and beacons), position errors with 3-sigma bounds, per-sensor NIS.

``plot_run(path, layout, estimates_t, estimates_x, estimates_sd, truth, beacons, nis, title)`` draws with
matplotlib's object API on the Agg canvas (no pyplot state, no display needed; matplotlib is imported
only when a plot is made, so loading the sinks stays cheap). Long runs are decimated to ``max_points``
samples per curve, so memory and time stay small whatever the length.

Panels:

- top view of the trajectory in the NED frame: east (``py``) to the right, north (``px``) up, equal
  axes; truth dashed; beacons as triangles with their names;
- position error per axis ``x_est - x_true`` (m) against time with the ``+-3 sigma`` band from the
  estimate's standard deviation (without truth: the band alone); the attitude error angle (deg) when the
  state has a quaternion block ``q`` and truth has ``qw qx qy qz``;
- NIS per sensor (log scale) with the two-sided 95% chi-square interval of its dimension and the fraction
  inside.
"""
from __future__ import annotations

import math
import os
from typing import Mapping

import numpy as np

from fusion.api import FusionError, StateLayout
from fusion.consistency import chi2_interval
from fusion.metrics import Truth, attitude_error_deg

__all__ = ["plot_run", "decimate_index", "EstimateBuffer"]


def decimate_index(n: int, max_points: int) -> np.ndarray:
    """Indices of at most ``max_points`` (about) evenly strided samples of ``n``, always with the last."""
    if n <= max_points:
        return np.arange(n)
    stride = math.ceil(n / max_points)
    idx = np.arange(0, n, stride)
    return idx if idx[-1] == n - 1 else np.r_[idx, n - 1]


class EstimateBuffer:
    """Keeps at most ``max_points`` estimates for a plot, in constant memory: when full, every other
    sample is dropped and the stride doubles. ``on_estimate(est)`` (a Sink-like method); ``arrays()`` ->
    ``(t (k,), x (k, n), sd (k, n))`` for ``plot_run``."""

    def __init__(self, max_points: int = 5000):
        self.max_points = max(2, int(max_points))
        self.stride, self._count = 1, 0
        self._t: list[float] = []
        self._x: list[np.ndarray] = []
        self._sd: list[np.ndarray] = []

    def on_estimate(self, estimate) -> None:
        if self._count % self.stride == 0:
            self._t.append(float(estimate.t))
            self._x.append(np.asarray(estimate.belief.x, dtype=float))
            self._sd.append(estimate.belief.sd)
            if len(self._t) >= self.max_points:
                self._t, self._x, self._sd = self._t[::2], self._x[::2], self._sd[::2]
                self.stride *= 2
        self._count += 1

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = self._x[0].size if self._x else 0
        return (np.asarray(self._t), np.asarray(self._x).reshape(-1, n), np.asarray(self._sd).reshape(-1, n))


def _position_names(layout: StateLayout) -> list[str]:
    if "p" in layout:
        return list(layout.block("p").element_names())
    return [n for n in ("px", "py", "pz") if n in layout.names]


def _quat_names(layout: StateLayout) -> list[str] | None:
    if "q" in layout and layout.block("q").kind == "quaternion":
        return list(layout.block("q").element_names())
    return None


def plot_run(path, layout: StateLayout, estimates_t: np.ndarray, estimates_x: np.ndarray,
             estimates_sd: np.ndarray, truth: Truth | None, beacons: Mapping[str, np.ndarray] | None,
             nis: Mapping[str, tuple] | None, title: str = "",
             max_points: int = 5000, truth_rows: np.ndarray | None = None) -> None:
    """Write the run plot as a PNG to ``path``.

    :param estimates_t: times (N,) in s; ``estimates_x``, ``estimates_sd``: states and standard
        deviations (N, n) in ``layout`` order (SI units).
    :param truth: the recording's truth or None; ``beacons``: name -> position (m, NED, 2 or 3 values).
    :param nis: ``{sensor: (times (k,), values (k,), dim)}`` (e.g. ``ErrorTracker.nis_series()``), or
        ``(times, values, dim, fraction)`` with the fraction inside the 95% interval over every update
        (when the values are a decimated subset, as from ``fusion.sinks.plot_recorder.PlotRecorder``).
    :param max_points: decimation per curve.
    :param truth_rows: the truth at each estimate time (N, m) in ``truth.names`` order (NaN rows where
        undefined), instead of interpolating ``truth`` (a streaming run keeps these, not the whole truth).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    t = np.asarray(estimates_t, dtype=float).reshape(-1)
    X = np.asarray(estimates_x, dtype=float).reshape(t.size, -1) if t.size else np.zeros((0, layout.n))
    SD = np.asarray(estimates_sd, dtype=float).reshape(t.size, -1) if t.size else np.zeros((0, layout.n))
    idx = decimate_index(t.size, max_points)
    t, X, SD = t[idx], X[idx], SD[idx]
    if truth_rows is not None:
        truth_rows = np.asarray(truth_rows, dtype=float).reshape(-1, len(truth.names) if truth is not None else 0)[idx]
    if truth is not None and len(truth) == 0:
        truth = None
    pos = _position_names(layout)
    pi = [layout.element_index(n) for n in pos]
    if truth_rows is not None and truth is not None and t.size:
        T = truth_rows
    else:
        T = truth.sample(t) if truth is not None and t.size else None   # truth at the (decimated) estimate times
    qn = _quat_names(layout)
    show_att = qn is not None and truth is not None and all(n in truth.index for n in qn)
    nis = {s: v for s, v in (nis or {}).items() if len(v[0])}

    n_err = max(1, len(pos)) + (1 if show_att else 0)
    n_nis_cols = min(3, max(1, len(nis)))
    n_nis_rows = math.ceil(len(nis) / n_nis_cols) if nis else 0
    fig = Figure(figsize=(13, 1.9 * n_err + 2.6 * n_nis_rows + 1.2), layout="constrained")
    FigureCanvasAgg(fig)
    if title:
        fig.suptitle(title)
    outer = fig.add_gridspec(2 if nis else 1, 1, height_ratios=[1.9 * n_err, 2.6 * n_nis_rows] if nis else None)
    top = outer[0].subgridspec(n_err, 2, width_ratios=[1.0, 1.4])

    # --- trajectory, top view (NED: east right, north up)
    ax = fig.add_subplot(top[:, 0])
    if len(pos) >= 2:
        ax.plot(X[:, pi[1]], X[:, pi[0]], lw=1.0, label="estimate")
        if truth is not None and all(n in truth.index for n in pos[:2]):
            ti = decimate_index(len(truth), max_points)
            ax.plot(truth.values[ti, truth.index[pos[1]]], truth.values[ti, truth.index[pos[0]]], "k--", lw=0.8,
                    label="truth")
        for name, b in (beacons or {}).items():
            b = np.asarray(b, dtype=float).reshape(-1)
            if b.size >= 2:
                ax.plot(b[1], b[0], "r^", ms=8)
                ax.annotate(str(name), (b[1], b[0]), textcoords="offset points", xytext=(4, 4), fontsize=8)
        ax.set_xlabel(f"{pos[1]}: east (m)")
        ax.set_ylabel(f"{pos[0]}: north (m)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.legend(loc="best", fontsize=8)
    elif len(pos) == 1:
        ax.plot(t, X[:, pi[0]], lw=1.0, label="estimate")
        if T is not None:
            ax.plot(t, T[:, truth.index[pos[0]]], "k--", lw=0.8, label="truth")
        ax.set_xlabel("t (s)")
        ax.set_ylabel(f"{pos[0]} (m)")
        ax.legend(loc="best", fontsize=8)
    else:
        ax.text(0.5, 0.5, "no position in the state", ha="center", va="center", transform=ax.transAxes)
    ax.set_title("trajectory (top view)")
    ax.grid(True, alpha=0.3)

    # --- position errors with 3-sigma bands
    first = None
    for k, (name, i) in enumerate(zip(pos, pi)):
        ax = fig.add_subplot(top[k, 1], sharex=first)
        first = first or ax
        band = 3.0 * SD[:, i]
        ax.fill_between(t, -band, band, color="tab:blue", alpha=0.2, lw=0, label="+-3 sigma")
        if T is not None and name in truth.index:
            ax.plot(t, X[:, i] - T[:, truth.index[name]], color="tab:red", lw=0.8, label="error")
        # robust limits: an initial transient (large sigma at start) must not squash the rest
        mag = np.abs(band)
        if T is not None and name in truth.index:
            mag = np.fmax(mag, np.abs(X[:, i] - T[:, truth.index[name]]))
        mag = mag[np.isfinite(mag)]
        if mag.size:
            lim = 1.3 * float(np.percentile(mag, 99.0))
            if lim > 0:
                ax.set_ylim(-lim, lim)
        ax.set_ylabel(f"{name} err (m)")
        ax.ticklabel_format(axis="y", useOffset=False)
        ax.grid(True, alpha=0.3)
        if k == 0:
            ax.set_title("position error" if T is not None else "position +-3 sigma (no truth)")
            ax.legend(loc="upper right", fontsize=8)
    if not pos:
        ax = fig.add_subplot(top[0, 1])
        ax.text(0.5, 0.5, "no position in the state", ha="center", va="center", transform=ax.transAxes)
    if show_att and T is not None:
        ax = fig.add_subplot(top[n_err - 1, 1], sharex=first)
        qi = [layout.element_index(n) for n in qn]
        qt = T[:, [truth.index[n] for n in qn]]
        ax.plot(t, attitude_error_deg(qt, X[:, qi]), color="tab:purple", lw=0.8)
        ax.set_ylabel("attitude err (deg)")
        ax.ticklabel_format(axis="y", useOffset=False)
        ax.grid(True, alpha=0.3)
        ax.set_xlabel("t (s)")
    elif pos:
        ax.set_xlabel("t (s)")  # the last position-error axes

    # --- NIS per sensor
    if nis:
        grid = outer[1].subgridspec(n_nis_rows, n_nis_cols)
        for k, (sensor, series) in enumerate(sorted(nis.items())):
            nt, nv, dim = series[:3]
            ax = fig.add_subplot(grid[k // n_nis_cols, k % n_nis_cols])
            nt, nv = np.asarray(nt, dtype=float), np.asarray(nv, dtype=float)
            lo, hi = chi2_interval(max(1, int(dim)))
            finite = np.isfinite(nv)
            inside = float(np.mean((nv[finite] >= lo) & (nv[finite] <= hi))) if finite.any() else float("nan")
            if len(series) > 3 and series[3] is not None:
                inside = float(series[3])
            j = decimate_index(nt.size, max_points)
            ax.plot(nt[j], np.clip(nv[j], 1e-6, None), ".", ms=2, color="tab:green")
            ax.axhline(hi, color="k", ls="--", lw=0.8)
            ax.axhline(max(lo, 1e-6), color="k", ls=":", lw=0.8)
            ax.set_yscale("log")
            ax.set_title(f"NIS {sensor} (dof {dim}): {inside:.0%} in 95% interval", fontsize=9)
            ax.set_xlabel("t (s)")
            ax.grid(True, alpha=0.3)
    from fusion.outputs import OutputFile

    fmt = plot_format(path)
    out = OutputFile(path, "wb", what="plot")
    try:
        fig.savefig(out.file, dpi=90, format=fmt)
    except OSError as exc:
        out.discard()
        raise FusionError(f"cannot write plot to {path}: {exc.strerror or exc}") from None
    except BaseException:
        out.discard()
        raise
    out.close()


def plot_format(path) -> str:
    """The image format of ``path`` by its suffix (png, pdf, svg, ... as matplotlib writes them); a
    FusionError listing the known ones otherwise."""
    from matplotlib.backend_bases import FigureCanvasBase

    known = FigureCanvasBase.get_supported_filetypes()
    suffix = os.path.splitext(str(path))[1].lower().lstrip(".")
    if suffix not in known:
        raise FusionError(f"--plot {path}: unknown image suffix {('.' + suffix) if suffix else '(none)'}; "
                          f"known: {', '.join('.' + k for k in sorted(known))}")
    return suffix
