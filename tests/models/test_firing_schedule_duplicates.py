"""The firing schedule against second reports of one pulse: a line repeated 1 mm longer, an echo
stamped with the direct pulse's time, an exact repeat. Taken as a firing, one such line in the first 2 s would
make the learnt period 2.9 us (the emission gap of the two reports) and every range its own cycle: no fix
for the whole run. Generator: the seven-beacon mine schedule (as tests/models/test_abps_fix_stage.py: beacon j of
cycle n fires at t0 + n 0.4 + j 0.05 s, the pulse arrives after |p - B| / c from a known route)."""
from __future__ import annotations

import numpy as np
import pytest

from fusion.api import BuildContext, Message
from fusion_plugins.solvers.firing_schedule import FiringSchedule
from fusion_plugins.solvers.ols_trilateration import OlsParams, OlsTrilateration

MINE = {f"B{i + 1}": np.array([5.0 * i, 0.1 if i % 2 == 0 else 2.9, -0.9]) for i in range(7)}
C = 343.0


def _route(t):
    return np.array([3.0 + 0.8 * t, 1.2 + 0.2 * np.sin(t), -0.75])


def _stream(n_cycles=20, period=0.4, spacing=0.05, t0=0.3, reach=12.0):
    """[(t_arrival s, beacon, range m)] in arrival order."""
    out = []
    for n in range(n_cycles):
        for j, name in enumerate(MINE):
            te = t0 + n * period + j * spacing
            ta = te
            for _ in range(8):
                ta = te + np.linalg.norm(_route(ta) - MINE[name]) / C
            r = float(np.linalg.norm(_route(ta) - MINE[name]))
            if r <= reach:
                out.append((ta, name, r))
    return sorted(out)


def _cycles(stream, period=None):
    sched = FiringSchedule(period, speed_of_sound=C, learn_s=2.0)
    return sched, [c for t, b, r in stream for c in sched.add(t, b, r)] + sched.flush()


def _with(stream, i, extra):
    """The stream with one extra line (t, beacon, range) right after line i."""
    return stream[:i + 1] + [extra] + stream[i + 1:]


@pytest.mark.parametrize("kind", ["1 mm longer", "echo 0.5 m longer, direct stamp", "exact repeat"])
def test_a_second_report_of_one_pulse_in_the_learning_window_is_one_pulse(kind):
    """The tester's line right after a B2 range at 0.86 s: the period is still 0.4 s, the cycles are those of
    the clean stream (the shorter range kept in its cycle), and the extra report is returned as a duplicate."""
    clean = _stream()
    i = next(j for j, (t, b, _) in enumerate(clean) if b == "B2" and t > 0.8)
    t, b, r = clean[i]
    extra = {"1 mm longer": (t, b, r + 0.001), "echo 0.5 m longer, direct stamp": (t, b, r + 0.5),
             "exact repeat": (t, b, r)}[kind]
    s0, ref = _cycles(clean)
    s1, got = _cycles(_with(clean, i, extra))
    assert s1.period == pytest.approx(0.4, abs=1e-6) and s1.period == s0.period
    assert got == ref and s1.splits == 0
    dup = s1.take_duplicates()
    assert len(dup) == 1 and dup[0][1][:3] == clean[i] and dup[0][0][:3] == extra
    assert s1.take_duplicates() == []


def test_a_second_report_after_learning_keeps_the_shorter_range():
    """After the learning window an echo reported first (longer) then the direct pulse: the cycle keeps the
    direct (shorter) range, no cycle is split."""
    clean = _stream()
    i = next(j for j, (t, b, _) in enumerate(clean) if b == "B3" and t > 5.0)
    t, b, r = clean[i]
    stream = clean[:i] + [(t, b, r + 0.8)] + clean[i:]
    s0, ref = _cycles(clean)
    s1, got = _cycles(stream)
    assert got == ref and s1.splits == 0 and len(s1.take_duplicates()) == 1


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("fraction", [0.01, 0.05, 0.2])
def test_random_near_duplicates_leave_the_cycles_alone(seed, fraction):
    """Random second reports (exact, 1 mm longer, an echo 0.3-1.5 m longer with the direct stamp) of 1-20 %
    of the ranges, the first ones inside the learning window: the same period and cycles as without."""
    rng = np.random.default_rng(seed)
    clean = _stream(30)
    stream = []
    for t, b, r in clean:
        stream.append((t, b, r))
        if rng.random() < fraction:
            stream.append((t, b, r + rng.choice([0.0, 0.001, rng.uniform(0.3, 1.5)])))
    s0, ref = _cycles(clean)
    s1, got = _cycles(stream)
    assert s1.period == pytest.approx(0.4, abs=1e-6)
    assert got == ref
    assert len(s1.take_duplicates()) == len(stream) - len(clean)


def test_a_period_the_slots_cannot_hold_is_refused_and_said():
    """A stream no period explains (each beacon at random times): the learnt period is refused, learning
    goes on to 3 x learn_s, then the cycles are runs of distinct beacons and a warning says why and what
    to give; no range is lost."""
    rng = np.random.default_rng(1)
    names = list(MINE)
    stream = sorted((float(t), names[int(rng.integers(7))], 3.0) for t in rng.uniform(0.0, 10.0, 150))
    sched = FiringSchedule(None, speed_of_sound=C, learn_s=2.0)
    cycles = [c for t, b, r in stream for c in sched.add(t, b, r)] + sched.flush()
    assert sched.unscheduled and sched.period is None
    assert sum(len(c) for c in cycles) == len(stream)
    for cyc in cycles:
        assert len({c[1] for c in cyc}) == len(cyc)
    (t, why), = sched.take_warnings()
    assert 5.9 < t < 6.5 and "firing period could not be learnt" in why and "firing_period" in why
    assert "refused" not in why and "spread" in why


def test_the_fix_stage_reports_the_duplicate_and_still_fixes():
    """Through ols_trilateration: the tester's case (a B2 line 1 mm longer at 0.86 s) gives the same fixes as
    the clean stream, an Event 'rejected' naming the line's range and a duplicate_pulses count."""
    clean = _stream()
    i = next(j for j, (t, b, _) in enumerate(clean) if b == "B2" and t > 0.8)
    t, b, r = clean[i]

    def fixes(stream):
        s = OlsTrilateration(OlsParams(z=-0.75, z_sd=0.0, speed_of_sound=C), BuildContext(beacons=MINE, sensor="abps"))
        out = [f for k, (t, b, r) in enumerate(stream) for f in s.feed(Message(t, "abps", (b, r), k))] + s.flush()
        return s, out

    s0, f0 = fixes(clean)
    s1, f1 = fixes(_with(clean, i, (t, b, r + 0.001)))
    assert len(f1) == len(f0) > 15
    assert all(np.array_equal(a.value, b.value) for a, b in zip(f0, f1))
    assert s1.counters["duplicate_pulses"] == 1
    ev = [e for e in s1.events if e.kind == "rejected"]
    assert len(ev) == 1 and "second report of the pulse" in ev[0].detail and f"{r + 0.001:.3f} m" in ev[0].detail
