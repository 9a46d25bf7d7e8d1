"""Constants the INS batch integration tabulates instead of computing at import."""
import numpy as np

from fusion_plugins.process import ins_batch


def test_gauss_legendre_nodes_are_numpys_to_a_few_ulp():
    x, w = np.polynomial.legendre.leggauss(4)
    # leggauss takes an eigensolution and one Newton step: its weights are a few ulp from the closed form
    # (18 -+ sqrt 30) / 72 and their last bits change between numpy releases (1.26 and 2.x differ by 2 ulp, the
    # literals are 5 ulp from the exact value); 8 eps relative is that rounding with room, not a digit of a release
    eps = np.finfo(float).eps
    np.testing.assert_allclose(ins_batch._GL_NODES, 0.5 * (x + 1.0), rtol=8 * eps, atol=0)
    np.testing.assert_allclose(ins_batch._GL_WEIGHTS, 0.5 * w, rtol=8 * eps, atol=0)
    # and they integrate a degree-7 polynomial on [0, 1] exactly
    s = ins_batch._GL_NODES
    assert abs(float(ins_batch._GL_WEIGHTS @ s ** 7) - 1.0 / 8.0) < 1e-15
