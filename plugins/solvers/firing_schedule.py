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

A cycle never spans more than its period and never holds a beacon twice: either would start a new
cycle (a split), e.g. after a jump of the receiver clock.
"""
from __future__ import annotations

import math

import numpy as np

Range = tuple[float, str, float, float]   # (arrival time s, beacon, range m, emission time s)


class FiringSchedule:
    """Groups ``(t, beacon, range)`` into firing cycles; ``add`` returns the cycles it closes (lists of
    :data:`Range`), ``flush`` the last one.

    :param period: firing period T (s) of the cycle, or None to learn it from the stream.
    :param speed_of_sound: m/s, to refer the arrival time to the emission time (None: the arrival time).
    :param learn_s: seconds of emissions from which the period (if not given) and the slot phases are learnt
        (with the period given: one period, or until each of ``expected`` beacons has fired once).
    """

    def __init__(self, period: float | None, speed_of_sound: float | None = None, learn_s: float = 2.0,
                 expected: int | None = None):
        self.period = period
        self.expected = expected
        self.c = speed_of_sound
        self.learn_s = learn_s
        self.cut: float | None = None           # emission time of a cycle boundary (s)
        self.splits = 0                         # cycles split (beacon twice or span > period)
        self._held: list[Range] = []            # ranges held while learning
        self._open: list[Range] = []
        self._open_k: int | None = None

    # ------------------------------------------------------------------ public
    def add(self, t: float, beacon: str, rng: float) -> list[list[Range]]:
        te = t - rng / self.c if self.c else t
        item = (t, beacon, rng, te)
        if self.cut is None:
            self._held.append(item)
            span = te - min(h[3] for h in self._held)
            # with the period given, one period of ranges (or every expected beacon once) shows the slots
            done = span >= self.learn_s or (self.period is not None and (
                span >= self.period or len({h[1] for h in self._held}) == self.expected))
            if not done:
                return []
            if not self._learn():
                return []
            held, self._held = self._held, []
            out: list[list[Range]] = []
            for h in sorted(held, key=lambda h: h[3]):
                out += self._assign(h)
            return out
        return self._assign(item)

    def flush(self) -> list[list[Range]]:
        """The cycle still open (end of input); while still learning, the held ranges with what was learnt
        (or each run of distinct beacons as a cycle when nothing could be learnt)."""
        out: list[list[Range]] = []
        if self.cut is None and self._held:
            learnt = self._learn()
            held, self._held = sorted(self._held, key=lambda h: h[3]), []
            if learnt:
                for h in held:
                    out += self._assign(h)
            else:
                cyc: list[Range] = []
                for h in held:
                    if any(c[1] == h[1] for c in cyc):
                        out.append(cyc)
                        cyc = []
                    cyc.append(h)
                out.append(cyc)
                return out
        if self._open:
            out.append(self._open)
            self._open, self._open_k = [], None
        return out

    def open_beacons(self) -> int:
        """Number of ranges in the open cycle."""
        return len(self._open)

    def close_open(self) -> list[Range]:
        """Close the open cycle now (every expected beacon has reported) and return it."""
        cyc, self._open, self._open_k = self._open, [], None
        return cyc

    # ------------------------------------------------------------------ internals
    def _assign(self, item: Range) -> list[list[Range]]:
        T = self.period
        k = math.floor((item[3] - self.cut) / T)  # type: ignore[operator]
        out: list[list[Range]] = []
        if self._open and (k > self._open_k or any(o[1] == item[1] for o in self._open)  # type: ignore[operator]
                           or item[3] - self._open[0][3] >= T):
            if k <= self._open_k:                 # type: ignore[operator]
                self.splits += 1                  # same cycle index, but a beacon twice or too long: split
            out.append(self._open)
            self._open = []
        if not self._open:
            self._open_k = k
        self._open.append(item)
        return out

    def _learn(self) -> bool:
        """Period (if not given) and cut from the held ranges; False when they do not tell yet."""
        by_beacon: dict[str, list[float]] = {}
        for _, b, _, te in self._held:
            by_beacon.setdefault(b, []).append(te)
        if self.period is None:
            gaps = np.concatenate([np.diff(sorted(v)) for v in by_beacon.values() if len(v) > 1] or [np.zeros(0)])
            gaps = gaps[gaps > 1e-6]
            if len(gaps) < 2:
                return False
            m = gaps.min()
            # np.median without its numpy.ma import (~10 ms of a run's start-up): the middle one, or the
            # mean of the middle two, of the sorted periods
            per = np.sort(gaps / np.maximum(np.round(gaps / m), 1.0))
            h = len(per) // 2
            self.period = float(per[h]) if len(per) % 2 else float((per[h - 1] + per[h]) / 2.0)
        T = self.period
        t0 = min(h[3] for h in self._held)
        # slot phase of each beacon (circular mean of its emissions modulo T)
        phases = []
        for v in by_beacon.values():
            a = 2.0 * np.pi * (np.asarray(v) - t0) / T
            phases.append((math.atan2(np.sin(a).mean(), np.cos(a).mean()) / (2.0 * np.pi) * T) % T)
        ph = np.sort(np.asarray(phases))
        if len(ph) == 1:
            self.cut = t0 + ph[0] + 0.5 * T
            return True
        gaps = np.diff(np.r_[ph, ph[0] + T])
        distinct = gaps[gaps > 1e-3 * T]
        spacing = float(distinct.min()) if len(distinct) else T
        i = int(np.argmax(gaps))
        self.cut = t0 + ph[i] + 0.5 * min(spacing, gaps[i])
        # the first cut at or before the first emission
        self.cut -= math.ceil((self.cut - t0) / T) * T
        return True
