"""``run(system, source, sinks)``: a whole run of a source through a ``Run`` session, its ends told apart
(Ctrl-C, a lost source, a process model that cannot go on, a component's bug) and always summarised."""
from __future__ import annotations

import math
from typing import Any, Callable, Sequence

from fusion.api import Event, FusionError, Message
from fusion.config import System
from fusion.logformat import iter_messages
from fusion.run.clock import COMPARED
from fusion.run.integrator import ProcessModelFailed
from fusion.run.lines import SourceLost, guarded, lines_of, source_message
from fusion.run.result import RunResult
from fusion.run.session import Run


def run(system: System, source: Any, sinks: Sequence[Any] = (), *, on_event: Callable[[Event], Any] | None = None,
        progress: Callable[[float], Any] | None = None, plot: Any = None, hooks: bool = True,
        label: str | None = None, on_truth: Callable[[Message], Any] | None = None) -> RunResult:
    """Run ``system`` over ``source`` (a recording path or source URL, a ``Source``, or an iterable of text
    lines) and return its ``RunResult``. ``sinks`` get every estimate and are closed at the end;
    ``on_truth`` every truth message, on the stream's time base (as ``Run``'s).

    Ctrl-C stops reading: what was read is processed, the sinks are closed and the result has
    ``interrupted=True``. A source that fails while it is read (an OSError or a FusionError from its lines,
    e.g. a lost link) ends the run the same way, what was read processed and summarised, the hooks
    called, with ``source_error`` saying why (``fusion run`` then exits 2). A process model that fails on
    every prediction (fusion.run.integrator.ProcessModelFailed) ends it so too, with ``component_error``; a
    model's failure in one update only loses that message (fusion.run.measure). A bug in a component ends the
    run with a RuntimeError that says how far it got; a component's ``FusionError`` (bad input the run
    cannot go on with) is raised as is, after the sinks are closed."""
    lines, name, close = lines_of(source, label)
    session = Run(system, sinks, on_event=on_event, progress=progress, plot=plot, hooks=hooks,
                  label=label if label is not None else name, on_truth=on_truth)
    interrupted = False
    source_error = component_error = None
    try:
        session.consume(iter_messages(guarded(lines), session.parsed, raw_streams=COMPARED))
    except KeyboardInterrupt:
        interrupted = True
    except SourceLost as exc:
        source_error = source_message(name, exc.__cause__ or exc)
    except ProcessModelFailed as exc:
        component_error = str(exc)
    except FusionError:
        session.close_sinks()
        raise
    except Exception as exc:
        session.close_sinks()
        last = session.last
        where = f"t = {last.t:.3f} s" if last is not None and math.isfinite(last.t) else "the start"
        raise RuntimeError(f"{exc} (the run got as far as {where}, {session.stats.estimates} estimates)") from exc
    finally:
        if close is not None:
            close()
    try:
        return session.finish(flush=component_error is None, interrupted=interrupted, source_error=source_error,
                              component_error=component_error)
    except KeyboardInterrupt:  # a second Ctrl-C while flushing: report what there is
        return session.finish(flush=False, interrupted=True, source_error=source_error,
                              component_error=component_error)
