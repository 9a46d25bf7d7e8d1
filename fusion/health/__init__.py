"""Whether a finished run's estimate can be trusted (DESIGN.md "Health and exit codes"): the ``health:``
limits (spec), a sink that watches a run's updates (watch), the rule (rule) and the likely causes it names
(causes). ``assess`` puts them together for a command."""
from __future__ import annotations

from typing import Any

from fusion.health.causes import RunContext, context_of
from fusion.health.rule import Finding, Verdict, judge
from fusion.health.spec import DEGRADED_EXIT, AgreementLimits, HealthSpec
from fusion.health.watch import HealthWatch

__all__ = ["DEGRADED_EXIT", "AgreementLimits", "Finding", "HealthSpec", "HealthWatch", "RunContext", "Verdict",
           "assess", "context_of", "judge", "spec_of"]


def spec_of(system: Any) -> HealthSpec:
    """The system's ``health:`` limits (the defaults for a spec without the section)."""
    return getattr(system.spec, "health", None) or HealthSpec()


def assess(system: Any, summary: dict[str, Any], watch: HealthWatch | dict | None, header: Any = None,
           recording: Any = None) -> Verdict:
    """The Verdict of a run of ``system`` from its ``summary`` and ``watch`` (a HealthWatch that saw its
    estimates, or such a watch's report; None: the summary alone), its recording's parsed ``header`` and
    file path or lines ``recording`` (for the causes); also written into ``summary["health"]`` (``degraded``,
    ``findings``)."""
    report = watch.report() if isinstance(watch, HealthWatch) else watch
    verdict = judge(summary, report, spec_of(system), context_of(system, header, recording))
    summary.setdefault("health", {}).update(verdict.as_dict())
    return verdict
