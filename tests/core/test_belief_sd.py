"""Belief.sd: sqrt of the covariance's diagonal with negative variances (rounding) read as 0, the same bits as
``np.sqrt(np.clip(np.diagonal(P), 0.0, None))`` (without np.clip's wrappers),
signed zeros, NaN, inf and integer covariances included."""
import numpy as np
import pytest

from fusion.api import Belief


@pytest.mark.parametrize("seed", range(5))
def test_sd_is_the_clipped_square_root_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    P = rng.normal(size=(7, 7))
    P[np.diag_indices(7)] = [-0.0, np.nan, -3.0, np.inf, 0.0, 2.25, -np.inf]
    sd = Belief(0.0, np.zeros(7), P=P).sd
    assert sd.tobytes() == np.sqrt(np.clip(np.diagonal(P), 0.0, None)).tobytes()
    assert np.signbit(sd[0]) == np.signbit(np.sqrt(np.clip(-0.0, 0.0, None))) and sd[5] == 1.5 and sd[2] == 0.0
    Pi = rng.integers(-3, 4, size=(4, 4))
    assert Belief(0.0, np.zeros(4), P=Pi).sd.tobytes() == np.sqrt(np.clip(np.diagonal(Pi), 0.0, None)).tobytes()


def test_square_root_belief_sd_is_the_row_norms():
    S = np.tril(np.arange(1.0, 10.0).reshape(3, 3))
    assert np.allclose(Belief(0.0, np.zeros(3), S=S).sd, np.sqrt(np.diag(S @ S.T)), rtol=1e-15, atol=0.0)
