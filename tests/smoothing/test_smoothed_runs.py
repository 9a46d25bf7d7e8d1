"""Smoothed runs end to end: through fusion.pipeline on the shipped configs and by ``fusion run``.

The forward pass is the filter's own (its summary equals the plain run's); the smoothed estimates come at
the filter's output times; the fixed-lag smoother with a lag longer than the run is the full smoother
and with lag 0 the filter; the disk store gives the same numbers; the square-root smoother equals the
covariance one on the 16-state INS (quaternion block, batched IMU runs)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fusion import pipeline
from fusion.config import load_system
from fusion.smoothing import run_smoothed

ROOT = Path(__file__).resolve().parents[2]


def _lines(config: str, seconds: float):
    system = load_system(ROOT / "configs" / config)
    with open(system.recording) as fh:
        lines = [ln for ln in fh if ln.startswith("#") or float(ln.split(",", 1)[0]) <= seconds]
    return system, lines


def _arrays(est):
    return (np.array([e.t for e in est]), np.array([e.belief.x for e in est]),
            np.array([e.belief.sd for e in est]))


@pytest.fixture(scope="module")
def uwb():
    return _lines("uwb_pv_ukf.yaml", 30.0)


def test_forward_pass_is_the_filters_own_and_smoothing_helps(uwb):
    system, lines = uwb
    plain = pipeline.Collect()
    ref = pipeline.run(system, lines, [plain])
    sm = pipeline.Collect()
    res = run_smoothed(system, lines, [sm])
    s = res.summary
    assert s["errors"] == ref.summary["errors"] and s["consistency"] == ref.summary["consistency"]
    assert s["steps"] == ref.summary["steps"]
    t0, x0, _ = _arrays(plain.estimates)
    t1, x1, sd1 = _arrays(sm.estimates)
    assert np.array_equal(t0, t1)
    assert [e.reason for e in sm.estimates] == [e.reason for e in plain.estimates]
    assert np.array_equal(x0[-1], x1[-1])             # the last smoothed estimate is the last filtered one
    assert (sd1 <= _arrays(plain.estimates)[2] + 1e-12).all()   # smoothing never widens a marginal
    sme = s["smoothed"]["errors"]
    assert sme["samples"] == s["errors"]["samples"]
    assert sme["position_rmse_m"] < 0.8 * s["errors"]["position_rmse_m"]


def test_fixed_lag_longer_than_the_run_is_the_full_smoother_and_lag_zero_the_filter(uwb):
    system, lines = uwb
    full, lagged, zero, plain = pipeline.Collect(), pipeline.Collect(), pipeline.Collect(), pipeline.Collect()
    run_smoothed(system, lines, [full])
    r = run_smoothed(system, lines, [lagged], lag=1e6)
    run_smoothed(system, lines, [zero], lag=0.0)
    pipeline.run(system, lines, [plain])
    a, b, c, d = (_arrays(k.estimates) for k in (full, lagged, zero, plain))
    for u, v in zip(a, b):
        assert np.abs(u - v).max() < 1e-12
    for u, v in zip(c, d):
        assert np.abs(u - v).max() < 1e-12
    assert r.summary["smoothed"]["smoother"] == "fixed_lag"


def test_fixed_lag_memory_is_bounded_by_its_window(uwb):
    system, lines = uwb
    short, long_ = pipeline.Collect(), pipeline.Collect()
    r = run_smoothed(system, lines, [short], lag=1.0)
    run_smoothed(system, lines, [long_])
    # 20 ranges a second: a 1 s window holds ~20 transitions, whatever the length of the run
    assert r.summary["smoothed"]["largest_window"] <= 25
    t, x, _ = _arrays(short.estimates)
    tf, xf, _ = _arrays(long_.estimates)
    assert np.array_equal(t, tf)
    # estimates more than the lag from the end are smoothed over 1 s only: close to, not equal to the full
    err = np.abs(x - xf)[t < t[-1] - 1.0].max()
    assert 0.0 < err < 0.2


def test_disk_store_same_numbers(uwb, tmp_path):
    system, lines = uwb
    mem, dsk = pipeline.Collect(), pipeline.Collect()
    run_smoothed(system, lines, [mem], disk=False)
    r = run_smoothed(system, lines, [dsk], disk=True, chunk=16)
    assert r.summary["smoothed"]["store"]["on_disk"] and r.summary["smoothed"]["store"]["bytes_on_disk"] > 0
    for u, v in zip(_arrays(mem.estimates), _arrays(dsk.estimates)):
        assert np.array_equal(u, v)


def test_square_root_equals_covariance_smoother_on_the_ins():
    """abps_ins (16 states, quaternion block, IMU runs between fixes in one sigma-point step): srukf
    and ukf smoothers agree; their forward filters agree to ~1e-9 and the backward pass adds little."""
    system, lines = _lines("abps_ins.yaml", 25.0)
    out = {}
    for name in ("srukf", "ukf"):
        sysn = load_system(ROOT / "configs" / "abps_ins.yaml", filter_override={"type": name, "alpha": 0.5})
        kept = pipeline.Collect()
        res = run_smoothed(sysn, lines, [kept])
        out[name] = (_arrays(kept.estimates), res.summary)
    (ts, xs, sds), s1 = out["srukf"]
    (tu, xu, sdu), s2 = out["ukf"]
    assert np.array_equal(ts, tu) and len(ts) > 30
    assert np.abs(xs - xu).max() < 1e-7
    assert np.abs(sds - sdu).max() < 1e-7
    q = xs[:, 6:10]
    assert np.abs(np.linalg.norm(q, axis=1) - 1.0).max() < 1e-12      # quaternions normalised
    assert s1["smoothed"]["errors"]["position_rmse_m"] < s1["errors"]["position_rmse_m"]


def _fusion(*args, cwd=ROOT):
    env = dict(os.environ, FUSION_DISABLE_PLUGIN_AUTOLOAD="1")
    return subprocess.run([sys.executable, "-m", "fusion.cli", *args], cwd=cwd, capture_output=True, text=True,
                          env=env)


def test_cli_smooth_writes_smoothed_csv_and_side_by_side_summary(tmp_path):
    csv, js = tmp_path / "s.csv", tmp_path / "s.json"
    p = _fusion("run", "configs/example_2d.yaml", "--smooth", "-o", str(csv), "--summary-json", str(js))
    assert p.returncode == 0, p.stderr
    assert "Filtered and smoothed" in p.stdout and "smoothed" in p.stdout
    s = json.loads(js.read_text())
    rows = csv.read_text().splitlines()
    assert len(rows) - 1 == s["smoothed"]["estimates"]
    assert s["smoothed"]["errors"]["samples"] == s["errors"]["samples"]
    assert s["smoothed"]["errors"]["position_rmse_m"] < s["errors"]["position_rmse_m"]


@pytest.mark.parametrize("args,needle", [
    (["--smooth-lag", "-2"], "--smooth-lag"),
    (["--smooth", "--filter", "ukf", "--filter-param", "augmented=true"], "augmented"),
])
def test_cli_bad_smoothing_is_one_clear_error(args, needle):
    p = _fusion("run", "configs/example_2d.yaml", "-q", *args)
    assert p.returncode == 2
    assert needle in p.stderr and "Traceback" not in p.stderr


def test_config_smoother_section(tmp_path):
    text = (ROOT / "configs" / "example_2d.yaml").read_text().replace("../recordings", str(ROOT / "recordings"))
    cfg = tmp_path / "c.yaml"
    cfg.write_text(text + "smoother: {lag_s: 0.5}\n")
    js = tmp_path / "s.json"
    p = _fusion("run", str(cfg), "-q", "--summary-json", str(js))
    assert p.returncode == 0, p.stderr
    s = json.loads(js.read_text())
    assert s["smoothed"]["smoother"] == "fixed_lag" and s["smoothed"]["lag_s"] == 0.5
    bad = tmp_path / "b.yaml"
    bad.write_text(text + "smoother: {lag_s: -1}\n")
    p = _fusion("run", str(bad), "-q")
    assert p.returncode == 2 and "smoother" in p.stderr and "Traceback" not in p.stderr


def test_a_recovery_reset_breaks_the_chain():
    """A reset (fusion.recovery) starts a new chain: nothing after it flows back, so before it (the filter
    locked out, every fix rejected) the smoothed estimates are the filtered ones; after it smoothing helps."""
    sys.path.insert(0, str(ROOT / "tests" / "core"))
    from test_recovery import _system

    system, lines = _system("fix", {"after_s": 1.0, "min_rejected": 3, "action": "reset", "blocks": ["p"]})
    plain, sm = pipeline.Collect(), pipeline.Collect()
    pipeline.run(system, lines, [plain])
    res = run_smoothed(system, lines, [sm])
    assert res.summary["health"]["resets"] == 1 and res.summary["smoothed"]["breaks"] == 1
    t, x, _ = _arrays(plain.estimates)
    ts, xs, _ = _arrays(sm.estimates)
    assert np.array_equal(t, ts)
    reset_t = next(e.t for e in plain.estimates if abs(e.belief.x[0] - 9.0) > 2.0)  # first estimate after it
    before = t < reset_t
    assert before.sum() > 5
    assert np.abs(xs[before] - x[before]).max() < 1e-9
    assert np.abs(xs[~before] - x[~before]).max() > 1e-3
