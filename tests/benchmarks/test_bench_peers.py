"""benchmarks/bench_peers.py --quick runs with FilterPy alone, writes its page, and stops loudly when a
peer's estimates disagree with the project's (no timings are asserted)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import filterpy  # noqa: E402,F401  (in the test extra: its absence is a failure, not a skip)

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "benchmarks" / "bench_peers.py"


def _run(tmp_path: Path, *extra: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, str(SCRIPT), "--quick", "--peers", "filterpy",
                           "--out", str(tmp_path / "peers.md"), *extra],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)


def test_quick_run_checks_agreement_and_writes_the_page(tmp_path):
    proc = _run(tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    page = (tmp_path / "peers.md").read_text()
    assert "python benchmarks/bench_peers.py --quick --peers filterpy" in page
    for peer in ("stonesoup", "navlie", "dynamax"):
        assert f"- {peer}: not asked for (--peers)" in page     # skipped peers are named, with the reason
    rows = [line for line in page.splitlines() if line.startswith("| ") and "| 1e-08 |" in line]
    names = {line.split("|")[2].strip() for line in rows}
    assert {"FilterPy UKF", "FilterPy EKF", "fusion srukf"} <= names
    for line in rows:                      # same model, same inputs: agreement to rounding (tolerance 1e-8)
        assert float(line.split("|")[3]) <= 1e-8
    assert "real time" in page and "Step time against state size" in page


def test_a_wrong_noise_fails_the_agreement_check(tmp_path):
    proc = _run(tmp_path, "--r-scale", "4")    # FilterPy given 4 R: its estimates must differ
    assert proc.returncode == 1
    assert "agreement check failed: FilterPy" in proc.stderr
    assert not (tmp_path / "peers.md").exists()
