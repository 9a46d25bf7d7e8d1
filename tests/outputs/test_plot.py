"""fusion.sinks.plot: what is drawn (the curves and their data) for 3-D and 2-D runs, with and without
truth, long runs decimated; and that a PNG is written."""
import numpy as np
import pytest
from matplotlib.figure import Figure

from fusion.api import Belief, Estimate, Message, StateLayout
from fusion.metrics import Truth
from scipy.stats import chi2
from fusion.sinks.plot import EstimateBuffer, decimate_index, plot_run

PNG = b"\x89PNG\r\n\x1a\n"


def check_png(path):
    data = path.read_bytes()
    assert data[:8] == PNG and data[12:16] == b"IHDR"
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    assert width > 400 and height > 200


@pytest.fixture
def drawn(monkeypatch):
    """The figures plot_run saves (their axes, lines and data), captured at savefig."""
    figures = []
    save = Figure.savefig

    def capture(self, *args, **kwargs):
        figures.append(self)
        return save(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", capture)
    return figures


def _axes(fig, title):
    return next(ax for ax in fig.axes if ax.get_title() == title or ax.get_title().startswith(title))


def _line(ax, label):
    return next(ln for ln in ax.get_lines() if ln.get_label() == label)


def test_plot_3d_with_truth_beacons_nis_long_run(tmp_path, drawn):
    lay = StateLayout.parse("p:3 v:3 q:4")
    names = lay.names
    tt = np.arange(0.0, 60.0, 0.05)
    rows = np.zeros((tt.size, 10))
    rows[:, 0], rows[:, 1], rows[:, 6] = 10 * np.cos(tt / 10), 10 * np.sin(tt / 10), 1.0
    truth = Truth.from_messages([Message(t, "truth", tuple(r)) for t, r in zip(tt, rows)], names)
    n = 100_000                                                # decimated to 5000 points
    t = np.linspace(0.0, tt[-1], n)                            # within the truth's span
    rng = np.random.default_rng(0)
    x = np.zeros((n, 10))
    x[:, 0], x[:, 1], x[:, 6] = 10 * np.cos(t / 10), 10 * np.sin(t / 10), 1.0
    x[:, :3] += 0.1 * rng.normal(size=(n, 3))
    sd = np.full((n, 10), 0.1)
    nis = {"uwb": (t[::20], rng.chisquare(1, n // 20), 1), "gps": (t[::100], rng.chisquare(3, n // 100), 3)}
    beacons = {"B1": np.array([0.0, 0.0, -1.0]), "B2": np.array([12.0, -12.0])}
    out = tmp_path / "run.png"
    plot_run(out, lay, t, x, sd, truth, beacons, nis, "test run")
    check_png(out)
    (fig,) = drawn
    idx = decimate_index(n, 5000)
    # trajectory, top view: east (py) right, north (px) up; the estimate decimated, the truth, the beacons
    top = _axes(fig, "trajectory (top view)")
    est = _line(top, "estimate")
    np.testing.assert_array_equal(est.get_xdata(), x[idx, 1])
    np.testing.assert_array_equal(est.get_ydata(), x[idx, 0])
    tru = _line(top, "truth")
    np.testing.assert_allclose(tru.get_ydata(), rows[:, 0])
    np.testing.assert_allclose(tru.get_xdata(), rows[:, 1])
    marks = sorted((float(ln.get_xdata()[0]), float(ln.get_ydata()[0])) for ln in top.get_lines()
                   if ln.get_marker() == "^")
    assert marks == [(-12.0, 12.0), (0.0, 0.0)]
    assert sorted(a.get_text() for a in top.texts) == ["B1", "B2"]
    # position errors: estimate minus truth at the estimate times, one axes per axis, +-3 sigma bands
    err_axes = [ax for ax in fig.axes if ax.get_ylabel().endswith(" err (m)")]
    assert [ax.get_ylabel() for ax in err_axes] == ["px err (m)", "py err (m)", "pz err (m)"]
    tt_dec = t[idx]
    for k, ax in enumerate(err_axes):
        e = _line(ax, "error")
        np.testing.assert_array_equal(e.get_xdata(), tt_dec)
        expect = x[idx, k] - np.interp(tt_dec, tt, rows[:, k])
        np.testing.assert_allclose(e.get_ydata(), expect, atol=1e-9)
        band = ax.collections[0].get_paths()[0].vertices[:, 1]
        assert band.max() == pytest.approx(0.3) and band.min() == pytest.approx(-0.3)
    att = next(ax for ax in fig.axes if ax.get_ylabel() == "attitude err (deg)")
    np.testing.assert_allclose(att.get_lines()[0].get_ydata(), 0.0, atol=1e-6)   # q is the truth's
    # NIS per sensor: the points and the 95% interval lines, the fraction inside in the title
    for sensor, (nt, nv, dim) in nis.items():
        ax = _axes(fig, f"NIS {sensor} (dof {dim}):")
        pts = ax.get_lines()[0]
        np.testing.assert_array_equal(pts.get_xdata(), nt)
        np.testing.assert_array_equal(pts.get_ydata(), np.clip(nv, 1e-6, None))
        lo, hi = chi2.ppf([0.025, 0.975], dim)    # the 95% interval, from scipy
        assert [float(ln.get_ydata()[0]) for ln in ax.get_lines()[1:]] == pytest.approx([hi, lo])
        assert f"{np.mean((nv >= lo) & (nv <= hi)):.0%} in 95% interval" in ax.get_title()


def test_plot_2d_without_truth_or_nis(tmp_path, drawn):
    lay = StateLayout.parse("p:2 v:2")
    t = np.linspace(0, 5, 50)
    x = np.c_[t, 2 * t, np.ones_like(t), 2 * np.ones_like(t)]
    out = tmp_path / "run2d.png"
    plot_run(out, lay, t, x, np.full_like(x, 0.2), None, None, None, "2-D, no truth")
    check_png(out)
    fig = drawn[0]
    top = _axes(fig, "trajectory (top view)")
    assert [ln.get_label() for ln in top.get_lines()] == ["estimate"]           # no truth, no beacons
    np.testing.assert_array_equal(top.get_lines()[0].get_xdata(), 2 * t)
    np.testing.assert_array_equal(top.get_lines()[0].get_ydata(), t)
    sig = _axes(fig, "position +-3 sigma (no truth)")
    assert not sig.get_lines() and sig.collections[0].get_paths()[0].vertices[:, 1].max() == pytest.approx(0.6)
    assert not any(ax.get_title().startswith("NIS") for ax in fig.axes)
    empty = tmp_path / "empty.png"
    plot_run(empty, lay, np.zeros(0), np.zeros((0, 4)), np.zeros((0, 4)), None, None, None, "empty")
    assert empty.read_bytes()[:8] == PNG


def test_decimation_and_buffer():
    idx = decimate_index(100_001, 5000)
    assert idx.size <= 5001 and idx[0] == 0 and idx[-1] == 100_000
    assert np.array_equal(decimate_index(10, 5000), np.arange(10))
    buf = EstimateBuffer(max_points=100)
    for k in range(10_000):
        buf.on_estimate(Estimate(float(k), Belief(float(k), np.array([k, 0.0]), P=np.eye(2)), "output"))
    t, x, sd = buf.arrays()
    assert 50 <= t.size < 100 and x.shape == (t.size, 2) and sd.shape == (t.size, 2)
    assert np.all(np.diff(t) == buf.stride) and t[0] == 0.0
