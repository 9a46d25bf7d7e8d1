"""``--smooth`` and ``--smooth-lag`` end to end on every shipped config (issue 17: "work on every shipped
config"): the sinks get one smoothed estimate per filtered one, at the same times, finite, with a valid
covariance; where the recording has truth the smoothed position is closer to it than the filtered one."""
from pathlib import Path

import numpy as np
import pytest

from fusion import pipeline
from fusion.config import load_system
from fusion.smoothing import run_smoothed

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = sorted(p.name for p in (ROOT / "configs").glob("*.yaml"))


def test_every_config_is_covered():
    assert {"abps_ins.yaml", "imu_gps_mag_ekf.yaml", "ultrasonic_3d_iekf.yaml", "ultrasonic_3d_pose.yaml",
            "uwb_pv_ukf.yaml", "example_2d.yaml"} <= set(CONFIGS)


@pytest.mark.parametrize("config", CONFIGS)
@pytest.mark.parametrize("lag", [None, 2.0], ids=["smooth", "smooth-lag-2"])
def test_smoothed_run_of_the_shipped_config(config, lag):
    system = load_system(ROOT / "configs" / config)
    fwd, sm = pipeline.Collect(), pipeline.Collect()
    result = run_smoothed(system, system.recording, [sm], lag=lag, forward_sinks=[fwd])
    assert len(sm.estimates) == len(fwd.estimates) > 10
    np.testing.assert_array_equal([e.t for e in sm.estimates], [e.t for e in fwd.estimates])
    X = np.array([e.belief.x for e in sm.estimates])
    P = np.array([e.belief.cov for e in sm.estimates])
    assert np.isfinite(X).all() and np.isfinite(P).all()
    assert (np.linalg.eigvalsh(0.5 * (P + np.swapaxes(P, 1, 2)))[:, 0] > -1e-9).all()
    # the smoother never claims more than it knows of the last estimate: there it is the filter's
    np.testing.assert_allclose(X[-1], fwd.estimates[-1].belief.x, atol=1e-9)
    # and never less than nothing: each smoothed variance at most the filtered one (RTS: P^s <= P)
    Pf = np.array([e.belief.cov for e in fwd.estimates])
    assert (np.einsum("kii->ki", P) <= np.einsum("kii->ki", Pf) * (1 + 1e-6) + 1e-12).all()
    s = result.summary
    sm_s = s["smoothed"]
    assert sm_s["smoother"] == ("rts" if lag is None else "fixed_lag")
    assert sm_s.get("unmatched_estimates", 0) == 0
    if "errors" in s and "position_rmse_m" in s["errors"]:
        assert sm_s["errors"]["position_rmse_m"] < s["errors"]["position_rmse_m"]
