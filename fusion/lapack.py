"""scipy's public LAPACK and BLAS wrappers (``scipy.linalg.lapack``, ``scipy.linalg.blas``), the names the core
and plugins import: the filters and solvers call the routines directly (``dpotrf``, ``dgeqrfp``, ``dtrsm``,
...) because their matrices are tiny and scipy's checking wrappers would cost more than the flops
(plugins/filters/linalg.py). New code may import ``scipy.linalg.lapack`` itself; this module adds nothing."""
from __future__ import annotations

from scipy.linalg import blas, lapack

__all__ = ["lapack", "blas"]
