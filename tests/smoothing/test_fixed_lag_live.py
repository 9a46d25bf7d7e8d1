"""The fixed-lag smoother beside a live run (fusion.smoothing.live, used by ``fusion tui --smooth-lag``):
the same numbers whether the run loop hands over each estimate as the scheduler yields it
(``pipeline.run``) or all of a message's estimates at once afterwards (``pipeline.Run.push``, the live
loop), and the same as ``run_smoothed(..., lag=L)``."""
from pathlib import Path

import numpy as np
import pytest

from fusion import pipeline
from fusion.config import load_system
from fusion.logformat import iter_messages
from fusion.smoothing import run_smoothed
from fusion.smoothing.live import attach_fixed_lag

ROOT = Path(__file__).resolve().parents[2]


def pushed(config: str, lag: float) -> tuple[list, object]:
    """The fixed-lag estimates of a run fed message by message through Run.push (the live loop), and its
    fixed-lag sink."""
    system = load_system(ROOT / "configs" / config)
    got: list = []
    wrapped, sink = attach_fixed_lag(system, lag, got.append)
    run = pipeline.Run(wrapped, [sink])
    with open(system.recording) as f:
        for item in iter_messages(f, run.parsed):
            run.push(item)
    run.scheduler_finish()
    run.finish()
    return got, sink


@pytest.mark.parametrize("config, lag", [("example_2d.yaml", 2.0), ("uwb_pv_ukf.yaml", 0.5)])
def test_push_loop_gives_the_numbers_of_the_batch_loop(config, lag):
    system = load_system(ROOT / "configs" / config)
    kept = pipeline.Collect()
    run_smoothed(system, system.recording, [kept], lag=lag)
    live, _ = pushed(config, lag)
    assert len(live) == len(kept.estimates) > 100
    np.testing.assert_array_equal([e.t for e in live], [e.t for e in kept.estimates])
    np.testing.assert_allclose(np.array([e.belief.x for e in live]), np.array([e.belief.x for e in kept.estimates]),
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.array([e.belief.cov for e in live]),
                               np.array([e.belief.cov for e in kept.estimates]), rtol=0, atol=1e-12)


def test_a_late_noted_estimate_is_placed_at_its_own_node():
    """Every estimate of a pushed run matches a recorded node's belief (none mapped by default)."""
    _, sink = pushed("example_2d.yaml", 1.0)
    assert sink.log.unmatched == 0
    assert sink.fixed.emitted > 100


def test_smooth_and_smooth_lag_together_are_refused(capsys):
    """--smooth and --smooth-lag together are refused, whichever order they come in (not one of them run silently)."""
    from pathlib import Path

    from fusion.cli import main

    cfg = str(Path(__file__).resolve().parents[2] / "configs" / "uwb_pv_ukf.yaml")
    for argv in (["--smooth", "--smooth-lag", "2"], ["--smooth-lag", "2", "--smooth"]):
        assert main(["run", cfg, "-q", *argv]) == 2
        assert "--smooth and --smooth-lag 2 exclude each other" in capsys.readouterr().err
