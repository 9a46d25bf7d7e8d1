"""Constants the INS batch integration tabulates instead of computing at import."""
import numpy as np

from fusion_plugins.process import ins_batch


def test_gauss_legendre_nodes_are_numpys_to_the_last_bit():
    x, w = np.polynomial.legendre.leggauss(4)
    assert ins_batch._GL_NODES.tolist() == (0.5 * (x + 1.0)).tolist()
    assert ins_batch._GL_WEIGHTS.tolist() == (0.5 * w).tolist()
    # and they integrate a degree-7 polynomial on [0, 1] exactly
    s = ins_batch._GL_NODES
    assert abs(float(ins_batch._GL_WEIGHTS @ s ** 7) - 1.0 / 8.0) < 1e-15
