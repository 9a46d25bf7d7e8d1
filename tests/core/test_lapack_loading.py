"""fusion.lapack: the names the project imports are scipy's public LAPACK/BLAS wrappers, nothing else."""
import numpy as np
import scipy.linalg

from fusion import lapack as fl


def test_the_functions_are_scipys_own():
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
