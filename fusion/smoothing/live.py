"""Fixed-lag smoothing beside a live run (``fusion tui --smooth-lag SECONDS``).

:func:`attach_fixed_lag` turns a system into one whose filter is recorded (``RecordingFilter``) and
returns, with it, the pipeline sink that feeds the fixed-lag smoother: run the returned system with that
sink among the sinks (``fusion.pipeline.Run`` or ``run``) and ``emit`` gets every estimate again,
smoothed, ``lag`` s of sensor time after the filter gave it (the rest when the sink is closed at the
end of the input). Memory is the window of the last ``lag`` s (nothing is stored for a backward pass
over the whole run). The filtered estimates the run gives its other sinks are unchanged (the recorder
calls the filter itself).
"""
from __future__ import annotations

import dataclasses
from typing import Any, Callable

from fusion.api import ConfigError, Estimate
from fusion.config import System

from .backward import FixedLag, state_difference
from .record import ForwardLog, RecordingFilter

__all__ = ["attach_fixed_lag", "LagSink"]


class LagSink:
    """The live run's sink of the fixed-lag smoother: notes each filtered estimate in the chain and
    releases the smoothed ones that are ``lag`` s old; ``close()`` (end of input) smooths the rest."""

    def __init__(self, log: ForwardLog, fixed: FixedLag):
        self.log = log
        self.fixed = fixed
        self.closed = False

    def on_estimate(self, est: Estimate) -> None:
        node = self.log.note_estimate(est)
        if node is not None:
            self.fixed.on_estimate(est, node)

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.fixed.finish()
            self.log.close()


def attach_fixed_lag(system: System, lag: float, emit: Callable[[Estimate], Any]) -> tuple[System, LagSink]:
    """``(recorded system, sink)`` for fixed-lag smoothing with ``lag`` s (>= 0) alongside a run (see
    the module). ConfigError when the filter has no smoother or the scheduler replays late messages."""
    from .run import input_max_hold, smoother_backend

    if system.spec.scheduler.late_policy == "replay":
        raise ConfigError("smoothing needs scheduler.late_policy: drop (a replay rewinds the recorded chain)")
    if not lag >= 0.0:
        raise ConfigError(f"--smooth-lag must be a number of seconds >= 0, got {lag}")
    backend = smoother_backend(system.filter)
    fixed = FixedLag(backend.sqrt, lag, system.process.normalize, state_difference(system.layout), emit)
    log = ForwardLog(backend, system.layout.n, on_step=fixed.on_step, keep=False, max_hold=input_max_hold(system))
    fixed.log = log
    return dataclasses.replace(system, filter=RecordingFilter(system.filter, log)), LagSink(log, fixed)
