"""The run of a system over a source: re-exported from fusion.run (its home) for the callers of
``fusion.pipeline.run``, ``Run``, ``RunResult``, ``Collect`` and ``RunStats`` (the live view, sweep, experiments)."""
from fusion.api import Message  # noqa: F401
from fusion.run.integrator import ProcessModelFailed  # noqa: F401
from fusion.run.session import (Collect, Run, RunResult, _guarded, _source_message, _SourceLost,  # noqa: F401
                                expected_fields, header_beacon_warnings, read_only, run, source_text, truth_warnings)
from fusion.run.stats import COUNTERS, RunStats  # noqa: F401

__all__ = ["run", "Run", "RunResult", "RunStats", "Collect", "COUNTERS"]
