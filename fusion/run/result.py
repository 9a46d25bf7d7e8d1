"""What a run leaves (:class:`RunResult`) and the sink that keeps every estimate in memory (:class:`Collect`)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fusion.api import Estimate, Event
from fusion.logformat import ParsedStream
from fusion.run.stats import RunStats

__all__ = ["Collect", "RunResult"]


class Collect:
    """A sink that keeps every estimate (``estimates``) and event (``events``) in memory: for tests,
    experiments and short runs that want arrays afterwards. It is the one place a run's memory grows
    with its length, and only when asked for."""

    def __init__(self) -> None:
        self.estimates: list[Estimate] = []
        self.events: list[Event] = []

    def on_estimate(self, estimate: Estimate) -> None:
        self.estimates.append(estimate)

    def on_event(self, event: Event) -> None:
        self.events.append(event)

    def close(self) -> None:
        pass

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(t (k,), x (k, n), sd (k, n))`` of the collected estimates."""
        est = self.estimates
        n = est[0].belief.x.size if est else 0
        return (np.array([e.t for e in est]), np.array([e.belief.x for e in est]).reshape(-1, n),
                np.array([e.belief.sd for e in est]).reshape(-1, n))


@dataclass
class RunResult:
    """What a run leaves: its ``summary`` (the ``--summary-json`` dict), its ``stats``, the ``last``
    estimate (None when there was none), the parse state (``parsed``: header and malformed lines),
    ``interrupted`` (Ctrl-C), the wall time, and ``source_error``: why the source stopped early (it raised
    an OSError or a FusionError, e.g. a lost link), None when it ended normally; ``component_error``: why the
    run stopped before the end of its input because a component cannot go on (the process model failed on
    every prediction: fusion.run.integrator.ProcessModelFailed), None otherwise; ``plugin_errors``: one line per
    observer of a plugin that raised (an observation hook, a plugin's sink), each naming the plugin: the
    run went on without it (``Run``), so the estimates and the summary are complete."""

    summary: dict[str, Any]
    stats: RunStats
    last: Estimate | None
    parsed: ParsedStream
    interrupted: bool
    wall_s: float
    source_error: str | None = None
    component_error: str | None = None
    plugin_errors: tuple[str, ...] = ()
    plugin_exceptions: tuple[BaseException, ...] = field(default=(), repr=False)
