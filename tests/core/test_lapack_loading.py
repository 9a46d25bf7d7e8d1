"""fusion.lapack: scipy's LAPACK/BLAS wrappers without ``import scipy.linalg`` (start-up, issue 9 item 5)."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import scipy.linalg

from fusion import lapack as fl

ROOT = Path(__file__).resolve().parents[2]


def test_the_functions_are_scipys_own():
    """Loaded directly or not, every routine the project calls is the very object scipy.linalg exposes."""
    for name in ("dpotrf", "dpotrs", "dtrtrs", "dgeqrf", "dgeqrfp", "dsyevd", "dpstrf"):
        assert getattr(fl.lapack, name) is getattr(scipy.linalg.lapack, name), name
    assert fl.blas.dtrsm is scipy.linalg.blas.dtrsm


def test_they_compute_what_scipy_computes():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(7, 12))
    P = A @ A.T
    L, info = fl.lapack.dpotrf(P, 1, 1)
    assert info == 0
    np.testing.assert_allclose(L, scipy.linalg.cholesky(P, lower=True), rtol=0, atol=1e-12)
    b = rng.normal(size=(7, 2))
    x, info = fl.lapack.dpotrs(L, b, lower=1)
    np.testing.assert_allclose(P @ x, b, atol=1e-10)


def _in_fresh_python(code: str) -> dict:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_no_scipy_linalg_at_import_and_a_later_import_shares_the_routines():
    got = _in_fresh_python(
        "import json, sys; from fusion.lapack import lapack, blas, loaded_directly\n"
        "before = 'scipy.linalg' in sys.modules\n"
        "import scipy.linalg\n"
        "print(json.dumps({'direct': loaded_directly, 'before': before,\n"
        "  'same': scipy.linalg.lapack.dpotrf is lapack.dpotrf and scipy.linalg.blas.dtrsm is blas.dtrsm,\n"
        "  'attr': hasattr(scipy.linalg, '_flapack')}))")
    assert got == {"direct": True, "before": False, "same": True, "attr": True}


def test_falls_back_to_the_ordinary_import_when_the_files_are_not_found():
    """A scipy laid out differently (no linalg/_flapack file where scipy 1.x keeps it): the ordinary import."""
    got = _in_fresh_python(
        "import json, importlib.machinery as m\n"
        "m.EXTENSION_SUFFIXES[:] = ['.nosuchsuffix']\n"
        "from fusion.lapack import lapack, loaded_directly\n"
        "import scipy.linalg\n"
        "print(json.dumps({'direct': loaded_directly, 'same': lapack.dpotrf is scipy.linalg.lapack.dpotrf}))")
    assert got == {"direct": False, "same": True}


def test_the_headline_run_never_imports_scipy_linalg():
    """The ~150 ms import is gone from ``fusion run configs/abps_ins.yaml`` and the UWB UKF."""
    for cfg in ("configs/abps_ins.yaml", "configs/uwb_pv_ukf.yaml"):
        got = _in_fresh_python(
            "import json, sys, io, contextlib\nfrom fusion.cli import main\n"
            f"with contextlib.redirect_stdout(io.StringIO()): rc = main(['run', {cfg!r}, '-q'])\n"
            "print(json.dumps({'rc': rc, 'scipy': sorted(k for k in sys.modules if k.startswith('scipy.linalg'))}))")
        assert got == {"rc": 0, "scipy": []}, cfg
