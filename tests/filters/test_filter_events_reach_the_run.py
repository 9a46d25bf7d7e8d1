"""A filter's repair (a covariance that is not positive definite) reaches the run as a value: the event
stream, the summary's events and filter counters, and the live view's health; nothing is kept in the
filter (tests/filters/test_filters_linalg.py has the problem: alpha = 1, beta = -1 on x' = x^2)."""
import numpy as np

from fusion import pipeline
from fusion.config import SystemSpec, wire
from fusion.registry import make_plugin_manager
from test_filters_linalg import Identity1 as LinalgIdentity1, Square as LinalgSquare  # the same problem


class Square(LinalgSquare):
    """x' = x^2 (1-D), registered under its own name for this module's config."""

    name = "test_square_run"


class Identity1(LinalgIdentity1):
    """z = x (1-D), registered under its own name."""

    name = "test_identity1_run"


def _system(flt: str):
    _, reg = make_plugin_manager()
    reg.add(Square)
    reg.add(Identity1)
    spec = SystemSpec.model_validate({
        "name": "repair", "process": "test_square_run",
        "filter": {"type": flt, "alpha": 1.0, "beta": -1.0, "kappa": 0.0, "linear_prediction": "never"},
        "initial": {"mean": {"x": [0.0]}, "sd": {"x": 1.0}},
        "sensors": {"s": {"model": "test_identity1_run", "noise": 1000.0}}})   # updates leave x = 0, P = 1
    return wire(spec, registry=reg)


def test_a_repair_reaches_the_event_stream_the_summary_and_the_live_view():
    for flt in ("ukf", "srukf"):
        system = _system(flt)
        events = []
        lines = ["# fields s z\n"] + [f"{k:.1f},s,0.0\n" for k in range(1, 4)]
        result = pipeline.run(system, lines, on_event=events.append)
        repairs = [e for e in events if e.kind == "not_positive_definite"]
        assert repairs and all(flt in e.detail and "repaired" in e.detail for e in repairs), (flt, events)
        assert result.summary["events"]["not_positive_definite"] == len(repairs)
        assert result.summary["filter_counters"]["not_positive_definite"] == len(repairs)
        assert np.isfinite(result.last.belief.x).all()
        assert not hasattr(system.filter, "counters") and not hasattr(system.filter, "events")


def test_the_live_view_counts_the_repairs():
    from fusion.tui.feed import LiveFeed

    snaps = []
    lines = ["# fields s z\n"] + [f"{k:.1f},s,0.0\n" for k in range(1, 4)]
    final = LiveFeed(_system("ukf"), lines, snaps.append, speed=0.0).run()
    assert final.health.repairs >= 1 and "repaired" in final.health.reason
    assert any(e.kind == "not_positive_definite" for e in final.events)
