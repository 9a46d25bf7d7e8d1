"""What a run checks of a recording against its config at its start and end: a ``# fields`` line against the
columns a sensor's component reads (:func:`expected_fields`), the beacons a header declares against the
config's (:func:`header_beacon_warnings`), truth that cannot be compared (:func:`truth_warnings`)."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from fusion.api import Event

if TYPE_CHECKING:
    from fusion.run.stats import RunStats

__all__ = ["expected_fields", "truth_warnings", "header_beacon_warnings", "fix_sensor_absent", "coverage_check",
           "COARSE_TRUTH_S", "BEACON_TOLERANCE_M", "ATTITUDE_ONLY_HZ"]

#: Estimates a second of a run started without its fix when the config sets no output.rate_hz (an
#: attitude-only run may have no update to emit an estimate at).
ATTITUDE_ONLY_HZ = 10.0


def fix_sensor_absent(system: Any, fields: dict) -> tuple[float | None, Event] | None:
    """A recording whose header names its streams (``# fields``, ``fields``) without ``initial.from_sensor`` (a
    flight log without GPS): ``(output rate or None, the warning)`` to start the filter without waiting for a fix
    that never comes; None otherwise."""
    fs = system.spec.initial.from_sensor
    inputs = [n for n, s in system.sensors.items() if s.role == "input"]
    if fs is None or fs in fields or not any(n in fields for n in inputs):
        return None
    rate = None if system.spec.output.rate_hz else ATTITUDE_ONLY_HZ
    return rate, Event(math.nan, "warning", fs, (
        f"the recording has no {fs!r} stream (no '# fields {fs}' line): the filter starts without its fix "
        f"(initial.from_sensor), from the configured prior position and velocity and the aligned attitude"
        + (" (initial_attitude: the reference's)" if "initial_attitude" in fields else "")
        + "; position and velocity are dead reckoning only, the attitude is the estimate to read"
        + (f" (estimates also at {rate:g} Hz, output.rate_hz)" if rate else "")))


def coverage_check(system: Any, sensor: str, meta: Any) -> tuple[dict | None, str | None]:
    """The header's IMU coverage against the input sensor's limits (fusion.imu_coverage): ``(facts for the
    summary's health or None, a warning or None)``."""
    from fusion.imu_coverage import assess

    spec = system.spec.sensors[sensor]
    return assess(sensor, meta, spec.min_coverage, spec.max_rotation_deg)


def expected_fields(runtime: Any, process: Any) -> tuple[tuple[str, ...] | None, str]:
    """(the names of the values a sensor's messages are read as, in order, and the component that reads
    them), or (None, "") when none declares them: the input's process (``input_fields``), else the first of
    the sensor's decoder, preprocessor and model that declares ``fields`` (past the decoder only when it is
    ``line``, which passes the values on as they are: another decoder's output is not the line's values)."""
    if runtime.role == "input":
        names = getattr(process, "input_fields", None)
        return (tuple(names), f"process {process.name!r}") if names else (None, "")
    chain = (runtime.decoder, runtime.preprocessor, runtime.model)
    if runtime.decoder is not None and runtime.decoder.name != "line":
        chain = (runtime.decoder,)
    for comp in chain:
        names = getattr(comp, "fields", None) if comp is not None else None
        if names:
            return tuple(names), f"{comp.kind} {comp.name!r}"
    return None, ""


def truth_warnings(stats: RunStats, unnamed: dict[str, int], state_names: Sequence[str]) -> list[Event]:
    """Warnings when truth (or reference) lines could not be compared: no ``# fields`` line names their
    columns, or truth has columns that are no state element while it lacks the state's position elements,
    or all of them (``x y`` for a state's ``px py``: a naming mismatch, not a state truth cannot give)."""
    events = []
    for stream, n in sorted(unnamed.items()):
        events.append(Event(math.nan, "warning", None, f"{n} {stream} line(s) but no '# fields {stream} ...' "
                            f"header line names their columns: not compared (the state's elements: "
                            f"{' '.join(state_names)})"))
    for stream, comp in (("truth", stats.truth), ("reference", stats.reference)):
        if comp is None:
            continue
        names = list(comp.window.names)
        foreign = [c for c in names if c not in state_names]
        absent = [n for n in state_names if n not in names]
        position = comp.tracker.position_group()
        if foreign and (len(absent) == len(state_names) or any(n in absent for n in position)):
            events.append(Event(math.nan, "warning", None, f"{stream} columns {' '.join(foreign)} are no element "
                                f"of the state, and the state's {' '.join(absent)} are not among the {stream} "
                                "columns: those are not compared (a column is compared when it has the "
                                "element's name)"))
        comp.flush()   # the estimates evaluated so far, scored (TruthComparison.SCORE_BATCH): their count
        w, compared = comp.window, comp.tracker.compared
        if w.received >= 2 and w.period > COARSE_TRUTH_S and compared > 2 * w.received:
            T = w.period
            events.append(Event(math.nan, "warning", None, f"{stream} every {T:.3g} s, sparser than the estimates "
                                f"({compared} compared against {w.received} {stream} samples): an error between "
                                f"two {stream} samples includes the linear interpolation's own (a T^2/8 for an "
                                f"acceleration a: {0.125 * T * T:.2g} m at 1 m/s^2)"))
    return events


#: Truth sample period (s) beyond which the end of a run warns that errors between samples include the
#: interpolation's: a T^2 / 8 at acceleration a, 5 mm at 1 m/s^2 for 0.2 s, the order of the best fixes here.
COARSE_TRUTH_S = 0.2


#: Distance (m) between a recording's declared beacon and the config's beyond which they disagree.
BEACON_TOLERANCE_M = 0.01


def header_beacon_warnings(declared: dict[str, tuple[float, ...]], configured: dict[str, np.ndarray]) -> list[Event]:
    """Warnings when the recording's header (``# beacon B5: x y z``, as ``fusion simulate`` writes it) names a
    beacon the config lacks (its ranges are all malformed) or puts one elsewhere than the config does (every
    range to it is then wrong by up to the distance). Nothing when the config has no beacons."""
    if not configured:
        return []
    events = []
    missing = [b for b in declared if b not in configured]
    if missing:
        events.append(Event(math.nan, "warning", None, f"the recording declares beacon(s) {', '.join(missing)} that "
                            f"the config does not define (defined: {', '.join(sorted(configured))})"))
    for name, pos in declared.items():
        mine = configured.get(name)
        if mine is None:
            continue
        d = len(mine)
        theirs = np.asarray(pos[:d] if len(pos) >= d else tuple(pos) + (0.0,) * (d - len(pos)), float)
        gap = float(np.linalg.norm(theirs - mine))
        if not gap <= BEACON_TOLERANCE_M:
            events.append(Event(math.nan, "warning", None, f"beacon {name} is at {list(map(float, pos))} in the "
                                f"recording's header and at {mine.tolist()} in the config ({gap:.3g} m apart)"))
    return events
