"""The run loop as small parts with one direction of data (DESIGN.md "The run loop"):

    clock.py       ClockGuard: wild stamps, clock jumps (a message's time before it is ordered)
    reorder.py     ReorderBuffer: holds messages max_latency s, releases them in time order
    inputs.py      PendingInputs: the input samples waiting to be integrated
    integrator.py  Integrator: advance(belief, t) -> (belief, items), runs of input samples
    startup.py     StartUp: the static start, the fixes before it, the first belief
    measure.py     measure(filter, belief, obs, R, plan, layout) -> Outcome: one update, as a function
    replay.py      ReplayLog: late_policy replay's snapshots and log
    plan.py        SensorPlan: each sensor's bound callables, resolved once
    tally.py       Tally: what the filter did (counts, events)
    checks.py      what plugins hand back, checked (a plugin's bug loses a message, not the run)
    process.py     Processor: one released message through its sensor
    loop.py        Loop: the orchestrator (push, finish, replay)
    session.py     Run: a loop over messages, to RunStats, sinks and hooks
    drive.py       run(system, source, sinks): a whole source through a Run, its ends told apart
    stats.py       RunStats: what a run counts, online in constant memory
"""
from fusion.run.integrator import ProcessModelFailed
from fusion.run.loop import Loop, Updated
from fusion.run.drive import run
from fusion.run.session import Collect, Run, RunResult
from fusion.run.stats import COUNTERS, RunStats

__all__ = ["Loop", "Updated", "Run", "RunResult", "Collect", "run", "RunStats", "COUNTERS", "ProcessModelFailed"]
