"""Firing cycles of sequentially firing beacons, from the firing schedule (not a solver component).

Paper 000 sec. IV: each beacon emits its ultrasonic pulse together with a radio pulse, periodically, the
beacons in turn; a receiver gathers one range per beacon in range and localises itself once it has
enough. Which ranges form one cycle is a property of the schedule, not of the receiver's luck: beacon b
fires at ``t_b + n T`` (period T, its slot phase t_b), so its n-th firing belongs to cycle
``floor((t_emit - t_cut) / T)`` for a fixed cut ``t_cut`` placed between two slots. A repeat of a beacon
never closes a cycle by itself: when a beacon early in the order comes into range, it joins the cycle of
its slot, never one of two cycles merged.

The emission time of a range is ``t_emit = t_arrival - r / c`` with the speed of sound ``c`` (when given;
the sensor stamps the arrival), so the slot phases do not jitter with the time of flight.

The period is taken from the config or learnt from the stream: the gaps between consecutive emissions of
one beacon are multiples of T (a missed range doubles one); T is their greatest common divisor, found as
the median of ``gap / round(gap / min gap)``. The slot phases are learnt on the same first stretch of the
stream (``learn_s``): the cut goes half a slot spacing after the last seen slot before the largest gap of
the seen phases (the idle time after the last beacon), so it lies between two slots of the grid even for
beacons that come into range later. Ranges are held (not lost) while learning.

**Two reports of one pulse** (two receiver channels, a logger stamping an echo with the direct pulse's
time, a retransmitted line): two firings of one beacon are a period apart, and a period holds the slot of
every other beacon heard, so two reports of one beacon whose emissions are closer than half the gap between
the slots of two different beacons are one pulse. While learning, such a gap is no period (a min gap of
microseconds would make every range its own cycle); in a cycle the shorter range is kept as the direct
path (an echo is always longer) and the other is returned by :meth:`FiringSchedule.take_duplicates`.

**A learnt period is checked**: every beacon's emissions must sit on its slot of the learnt grid, its
circular spread under a quarter of the smallest slot spacing (the slots must hold the beacons heard
apart). A period that fails is refused and learning goes on over more of the stream (up to
``LEARN_MAX`` x ``learn_s``); when it still fails the cycles are runs of distinct beacons (a repeat closes
one) and :meth:`FiringSchedule.take_warnings` says why, so that ``firing_period`` can be given.

A cycle never spans more than its period and never holds a beacon twice: either would start a new
cycle (a split), e.g. after a jump of the receiver clock.

**Closing at the last heard slot** (``close_at_last_slot``): a cycle's data ends with the range of the last
beacon in the firing order that the receiver hears. Waiting for a range of the next cycle to close it adds up
to a period of delay (with a dozen beacons and only the nearer half in reach, 0.3-0.5 s), over which the
filter may integrate inputs: the fix is then applied to a belief that much later than its data and bridged
back with the belief's velocity (``age``), which an accelerating vehicle makes wrong. The beacons heard in the
last ``EXPECT_CYCLES`` cycles are expected; a cycle closes as soon as the latest of their slots has reported.
A beacon that comes into reach with a later slot reports after its cycle was closed: that range is returned
by :meth:`FiringSchedule.take_late` (dropped; the next cycles expect the beacon). When the beacon of the last
expected slot goes out of reach, the cycle closes by a range of the next one, as without the option, until
it is forgotten (``EXPECT_CYCLES`` cycles).
"""
from __future__ import annotations

import math

import numpy as np

Range = tuple[float, str, float, float]   # (arrival time s, beacon, range m, emission time s)
LEARN_MAX = 3.0          # learning may go on over this many learn_s when the learnt period is refused
MAX_SPREAD = 0.25        # largest circular sd of a beacon's emissions, in smallest slot spacings
EXPECT_CYCLES = 3        # a beacon heard in the last this many cycles (this one included) is expected in a cycle


class FiringSchedule:
    """Groups ``(t, beacon, range)`` into firing cycles; ``add`` returns the cycles it closes (lists of
    :data:`Range`), ``flush`` the last one.

    :param period: firing period T (s) of the cycle, or None to learn it from the stream.
    :param speed_of_sound: m/s, to refer the arrival time to the emission time (None: the arrival time).
    :param learn_s: seconds of emissions from which the period (if not given) and the slot phases are learnt
        (with the period given: one period, or until each of ``expected`` beacons has fired once).
    :param close_at_last_slot: close a cycle as soon as the last slot of the beacons heard lately has
        reported (module doc), not when a range of the next cycle arrives.
    """

    def __init__(self, period: float | None, speed_of_sound: float | None = None, learn_s: float = 2.0,
                 expected: int | None = None, close_at_last_slot: bool = False):
        self.period = period
        self.expected = expected
        self.c = speed_of_sound
        self.learn_s = learn_s
        self.cut: float | None = None           # emission time of a cycle boundary (s)
        self.splits = 0                         # cycles split (beacon twice or span > period)
        self._held: list[Range] = []            # ranges held while learning
        self._open: list[Range] = []
        self._open_k: int | None = None
        self.slot: float | None = None          # smallest spacing of two beacons' slots (s), once learnt
        self.unscheduled = False                # no period could be learnt: cycles are runs of distinct beacons
        self._duplicates: list[tuple[Range, Range]] = []   # (dropped, kept) reports of one pulse
        self._warnings: list[tuple[float, str]] = []       # (time s, why) for the user
        self._refused: str | None = None        # why the last learnt period was refused
        self.close_at_last_slot = close_at_last_slot
        self._heard: dict[str, tuple[int, float]] = {}   # beacon -> (cycle index, slot offset s) when last heard
        self._closed_k: int | None = None       # index of the last cycle closed before a later cycle's range
        self._closed: list[Range] = []          # ... and its ranges (a second report of one of its pulses)
        self._late: list[Range] = []            # ranges of a cycle already closed at its last heard slot

    # ------------------------------------------------------------------ public
    def add(self, t: float, beacon: str, rng: float) -> list[list[Range]]:
        te = t - rng / self.c if self.c else t
        item = (t, beacon, rng, te)
        if self.unscheduled:
            return self._assign_unscheduled(item)
        if self.cut is None:
            self._held.append(item)
            span = te - min(h[3] for h in self._held)
            # with the period given, one period of ranges (or every expected beacon once) shows the slots
            done = span >= self.learn_s or (self.period is not None and (
                span >= self.period or len({h[1] for h in self._held}) == self.expected))
            if not done:
                return []
            held = sorted(self._held, key=lambda h: h[3])
            if not self._learn():
                # too few gaps yet: hold on (as ever); a period refused: over LEARN_MAX learn_s at most
                if self._refused is None or span < LEARN_MAX * self.learn_s:
                    return []
                self._give_up(t, span)
                self._held = []
                out = []
                for h in held:
                    out += self._assign_unscheduled(h)
                return out
            self._held = []
            out = []
            for h in held:
                out += self._assign(h)
            return out
        return self._assign(item)

    def take_duplicates(self) -> list[tuple[Range, Range]]:
        """The reports dropped as a second report of one pulse since the last call, each with the one kept."""
        d, self._duplicates = self._duplicates, []
        return d

    def take_late(self) -> list[Range]:
        """The ranges that came after their cycle was closed at its last heard slot (a beacon newly in reach
        with a later slot), since the last call; dropped from the cycles."""
        d, self._late = self._late, []
        return d

    def take_warnings(self) -> list[tuple[float, str]]:
        """What the user should know about the schedule since the last call: (time s, message)."""
        w, self._warnings = self._warnings, []
        return w

    def flush(self) -> list[list[Range]]:
        """The cycle still open (end of input); while still learning, the held ranges with what was learnt
        (or each run of distinct beacons as a cycle when nothing could be learnt)."""
        out: list[list[Range]] = []
        if self.cut is None and self._held and not self.unscheduled:
            learnt = self._learn()
            held, self._held = sorted(self._held, key=lambda h: h[3]), []
            if learnt:
                for h in held:
                    out += self._assign(h)
            else:
                if self._refused is not None:
                    self._give_up(held[-1][0], held[-1][3] - held[0][3])
                self.unscheduled = True
                for h in held:
                    out += self._assign_unscheduled(h)
        if self._open:
            out.append(self._open)
            self._open, self._open_k = [], None
        return out

    def open_beacons(self) -> int:
        """Number of ranges in the open cycle."""
        return len(self._open)

    def close_open(self) -> list[Range]:
        """Close the open cycle now (every expected beacon has reported) and return it."""
        cyc, self._closed_k, self._closed = self._open, self._open_k, self._open
        self._open, self._open_k = [], None
        return cyc

    # ------------------------------------------------------------------ internals
    def _assign(self, item: Range) -> list[list[Range]]:
        T = self.period
        k = math.floor((item[3] - self.cut) / T)  # type: ignore[operator]
        out: list[list[Range]] = []
        if self._open and self._same_pulse(item):
            return out
        if not self._open and k == self._closed_k:
            # a range of the cycle closed at its last heard slot: a second report of one of its pulses, or a
            # beacon come into reach with a later slot (expected from now on)
            if not self._same_pulse(item, self._closed):
                self._late.append(item)
                self._heard[item[1]] = (k, item[3] - self.cut - k * T)  # type: ignore[operator]
            return out
        if self._open and (k > self._open_k or any(o[1] == item[1] for o in self._open)  # type: ignore[operator]
                           or item[3] - self._open[0][3] >= T):
            if k <= self._open_k:                 # type: ignore[operator]
                self.splits += 1                  # same cycle index, but a beacon twice or too long: split
            out.append(self._open)
            self._open = []
        if not self._open:
            self._open_k = k
        self._open.append(item)
        if self.close_at_last_slot:
            offset = item[3] - self.cut - k * T   # type: ignore[operator]
            # the latest slot of the beacons heard in the previous cycles (none: the first cycle waits)
            last = max((o for kb, o in self._heard.values() if k - EXPECT_CYCLES < kb < k), default=None)
            self._heard[item[1]] = (k, offset)
            if last is not None and offset >= last - 0.5 * self.slot:   # type: ignore[operator]
                out.append(self.close_open())       # the latest slot expected has reported
        return out

    def _same_pulse(self, item: Range, cycle: list[Range] | None = None) -> bool:
        """Whether ``item`` is a second report of the pulse of a range of its beacon in the open cycle (or in
        ``cycle``) (emissions closer than half the smallest slot spacing); if so the shorter range stays in the
        open cycle (the direct path) and the other is recorded as a duplicate; in a closed ``cycle`` the
        range already used is kept."""
        cyc = self._open if cycle is None else cycle
        for j, o in enumerate(cyc):
            if o[1] == item[1] and abs(item[3] - o[3]) < 0.5 * self.slot:   # type: ignore[operator]
                keep, drop = (item, o) if item[2] < o[2] and cycle is None else (o, item)
                cyc[j] = keep
                self._duplicates.append((drop, keep))
                return True
        return False

    def _assign_unscheduled(self, item: Range) -> list[list[Range]]:
        """Without a schedule: a cycle is a run of distinct beacons, closed by a repeat of one."""
        out: list[list[Range]] = []
        if any(o[1] == item[1] for o in self._open):
            out.append(self._open)
            self._open = []
        self._open.append(item)
        return out

    def _give_up(self, t: float, span: float) -> None:
        self.unscheduled = True
        self._warnings.append((t, f"the firing period could not be learnt from the first {span:.3g} s of ranges "
                                  f"({self._refused}); each run of distinct beacons is taken as a cycle. Give "
                                  f"the beacons' period as firing_period"))

    def _learn(self) -> bool:
        """Period (if not given) and cut from the held ranges; False when they do not tell yet (or the learnt
        period is refused: ``_refused`` says why)."""
        by_beacon = self._pulses()
        learnt = self.period is None
        if learnt:
            gaps = np.concatenate([np.diff(v) for v in by_beacon.values() if len(v) > 1] or [np.zeros(0)])
            gaps = gaps[gaps > 1e-6]
            if len(gaps) < 2:
                return False
            m = gaps.min()
            # np.median without its numpy.ma import (slow at a run's start-up): the middle one, or the
            # mean of the middle two, of the sorted periods
            per = np.sort(gaps / np.maximum(np.round(gaps / m), 1.0))
            h = len(per) // 2
            T = float(per[h]) if len(per) % 2 else float((per[h - 1] + per[h]) / 2.0)
        else:
            T = self.period
        t0 = min(h[3] for h in self._held)
        # slot phase of each beacon (circular mean of its emissions modulo T) and its spread (circular sd, s)
        phases, spread = [], 0.0
        for v in by_beacon.values():
            a = 2.0 * np.pi * (np.asarray(v) - t0) / T
            s, c = np.sin(a).mean(), np.cos(a).mean()
            phases.append((math.atan2(s, c) / (2.0 * np.pi) * T) % T)
            if learnt and len(v) > 1:
                spread = max(spread, math.sqrt(-2.0 * math.log(min(1.0, max(math.hypot(s, c), 1e-300)))) * T / (2.0 * np.pi))
        ph = np.sort(np.asarray(phases))
        gaps = np.diff(np.r_[ph, ph[0] + T])
        distinct = gaps[gaps > 1e-3 * T]
        spacing = float(distinct.min()) if len(distinct) and len(ph) > 1 else T
        if learnt and spread > MAX_SPREAD * spacing:
            # the emissions do not sit on the learnt grid's slots: the period is refused
            self._refused = (f"a learnt period of {T:.6g} s leaves the emissions of a beacon spread over "
                             f"{spread:.3g} s (circular sd) against slots {spacing:.3g} s apart")
            return False
        self.period, self.slot = T, spacing
        if len(ph) == 1:
            self.cut = t0 + ph[0] + 0.5 * T
            return True
        i = int(np.argmax(gaps))
        self.cut = t0 + ph[i] + 0.5 * min(spacing, gaps[i])
        # the first cut at or before the first emission
        self.cut -= math.ceil((self.cut - t0) / T) * T
        return True

    def _pulses(self) -> dict[str, list[float]]:
        """The emission times (s, sorted) of each beacon's pulses in the held ranges. Two emissions of one
        beacon closer than half the median gap between consecutive emissions of two different beacons are one
        pulse reported twice: the shorter range's (the direct path) stands for it."""
        held = sorted(self._held, key=lambda h: h[3])
        d = sorted(b[3] - a[3] for a, b in zip(held, held[1:]) if a[1] != b[1])
        h = len(d) // 2
        tol = 0.5 * (d[h] if len(d) % 2 else 0.5 * (d[h - 1] + d[h])) if d else 0.0
        by_beacon: dict[str, list[tuple[float, float]]] = {}
        for _, b, r, te in held:
            v = by_beacon.setdefault(b, [])
            if v and te - v[-1][0] < tol:
                if r < v[-1][1]:
                    v[-1] = (te, r)
            else:
                v.append((te, r))
        return {b: [te for te, _ in v] for b, v in by_beacon.items()}
