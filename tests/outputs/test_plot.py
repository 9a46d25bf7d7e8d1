"""fusion.sinks.plot: a valid, non-trivial PNG for 3-D and 2-D runs, with and without truth, long runs decimated."""
import numpy as np

from fusion.api import Belief, Estimate, Message, StateLayout
from fusion.metrics import Truth
from fusion.sinks.plot import EstimateBuffer, decimate_index, plot_run

PNG = b"\x89PNG\r\n\x1a\n"


def check_png(path):
    data = path.read_bytes()
    assert data[:8] == PNG and data[12:16] == b"IHDR"
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    assert width > 400 and height > 200
    assert len(data) > 20_000


def test_plot_3d_with_truth_beacons_nis_long_run(tmp_path):
    lay = StateLayout.parse("p:3 v:3 q:4")
    names = lay.names
    tt = np.arange(0.0, 60.0, 0.05)
    rows = np.zeros((tt.size, 10))
    rows[:, 0], rows[:, 1], rows[:, 6] = 10 * np.cos(tt / 10), 10 * np.sin(tt / 10), 1.0
    truth = Truth.from_messages([Message(t, "truth", tuple(r)) for t, r in zip(tt, rows)], names)
    n = 100_000                                                # decimated to 5000 points
    t = np.linspace(0.0, 60.0, n)
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


def test_plot_2d_without_truth_or_nis(tmp_path):
    lay = StateLayout.parse("p:2 v:2")
    t = np.linspace(0, 5, 50)
    x = np.c_[t, 2 * t, np.ones_like(t), 2 * np.ones_like(t)]
    out = tmp_path / "run2d.png"
    plot_run(out, lay, t, x, np.full_like(x, 0.2), None, None, None, "2-D, no truth")
    check_png(out)
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
