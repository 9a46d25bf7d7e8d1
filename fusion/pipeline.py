"""The run of a system over a source: re-exported from fusion.run (its home) for the callers of
``fusion.pipeline.run``, ``Run``, ``RunResult``, ``Collect`` and ``RunStats`` (the live view, sweep, experiments)."""
from fusion.api import Message  # noqa: F401
from fusion.run.header import expected_fields, header_beacon_warnings, truth_warnings  # noqa: F401
from fusion.run.integrator import ProcessModelFailed  # noqa: F401
from fusion.run.lines import SourceLost as _SourceLost, guarded as _guarded, source_message as _source_message  # noqa: F401
from fusion.run.lines import source_text  # noqa: F401
from fusion.run.observers import read_only  # noqa: F401
from fusion.run.drive import run  # noqa: F401
from fusion.run.session import Collect, Run, RunResult  # noqa: F401
from fusion.run.stats import COUNTERS, RunStats  # noqa: F401

__all__ = ["run", "Run", "RunResult", "RunStats", "Collect", "COUNTERS"]
