"""Time sanity per sensor: wild stamps, clock jumps and restarts (issue 10 item 2).

A stream's time base is the newest accepted time. A message whose stamp (after the sensor's
``time_offset`` and any re-synchronisation) is within ``future_s`` seconds of it, ahead or behind, is on
the base and goes on as usual (a little late is the scheduler's late policy). A stamp farther away is
**held**, never fed and never moving the horizon, until the sensor's next messages decide:

- the next message of the sensor is on the base again: the held stamp was wild (a bit flip, ``1e20``, a
  cut fragment such as ``560000``); it is dropped and counted malformed, with a ``time`` event;
- ``agree`` messages in a row agree on a new base (each ahead of the previous by at most ``future_s``, or
  at all when no other stream has spoken since the first was held: a sensor slower than 1 / ``future_s``):
  the sensor's clock jumped or restarted. If other sensors kept arriving on the old base meanwhile, or the
  new base is behind (a clock reset to 0), the sensor is **re-synchronised**: an offset maps its stamps
  onto the stream's base (the first held message lands at the newest accepted time when it came) and
  is applied to every later message of it (kept as small as the stream allows, so its messages never
  land behind the newest time); a ``clock`` event says by how much. If nothing arrived on the old base
  meanwhile (a message of another stream admitted since counts only when it is on the old base, not one
  already on the new base) and the new one is ahead, the whole stream moved on together, by however much:
  a pause in the recording, not a clock fault (there is no old time left to re-synchronise to). The held
  messages are released at their own times, and so are the messages the other streams (truth included)
  hold on the same new base (their first messages after the pause, which would otherwise be dropped as
  wild when their next message came); the scheduler predicts over the gap (bounded to its
  ``max_predict_s``). The stamps are kept.

**Cadence** (the scheduler's ``cadence_k``, default 2, and ``cadence_floor_s``, default 0.02 s). A stamp
inside ``future_s`` can still be wild: a bit flip 1 s ahead, taken as real, moves the stream's newest
time 1 s on and the correct messages of the other sensors that follow are late. So each sensor fed to
the filter has a learned spacing: the median of its last ``_SAMPLES`` block spacings, each the mean
spacing of a block of its messages (2, 4, 8, then ``_BLOCK``): robust to a dropout or a burst (one
block), bounded memory, a few float operations a message. The stream's spacing is that of the sensors'
messages merged, 1 / (the sum of their rates), over the sensors on their cadence (one that fell silent
no longer counts). With ``d`` how far a stamp (corrected as above) is past the stream's newest time plus
the reorder window (``max_latency``), the message is **held** when ``d > cadence_floor_s`` and it is

- ahead of its own sensor's newest stamp by more than ``cadence_k`` x that sensor's spacing +
  ``cadence_floor_s``, or
- past the window by more than ``cadence_k`` x the stream's spacing + ``cadence_floor_s`` (it would
  overtake the next messages of the fastest sensors, which would then be late).

Before a spacing is known (start-up: a sensor's first message, the first blocks) its bound is
``cadence_floor_s``. A stamp past the window by at most the floor is never held (sensors' clocks jitter
by that much), whatever gap came before it: a GPS back from a dropout while the IMU went on is on the
stream's time and goes on at once. A held message never moves the horizon and delays no other sensor's
message; it is decided by

- its sensor's next message stamped before it: it was wild; dropped and counted malformed, ``time`` event;
- its sensor's next message stamped at or after it (the sensor goes on from it: a real gap, a rate
  change, an irregular or event-driven sensor), or any other sensor's message at or after its time (the
  stream reached it): it is released at its own time, just before that message, so the messages go on
  in the recording's order and the outputs are those of an unguarded run;
- the end of the input: released (nothing contradicted it).

A pause of the whole stream shorter than ``future_s`` is such a gap: each sensor's first message after
it is held until its next message or the stream reaches it. Nothing the bound holds is lost unless its
own sensor's next stamp goes back before it (a sensor whose stamps jitter by more than its spacing,
``max_latency`` and the floor together); a wild stamp ahead by less than the bound is taken as real, as
before (what it overtakes by more than ``max_latency`` is late). ``cadence_k: 0`` turns the bound off.

``admit`` returns the messages to feed now, each with its corrected time, and the events to report;
``steady`` is the scheduler's fast path for a message that needs no decision.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from fusion.api import Event, Message

__all__ = ["ClockGuard", "COMPARED"]

#: Streams compared against, never fed (the pipeline's truth and reference lines go through the same guard).
COMPARED = frozenset(("truth", "reference"))


_BLOCK = 16   # messages per spacing sample once started (the first samples: 2, 4 and 8 messages)
_SAMPLES = 3  # spacing samples kept; the spacing is their median


class _Cadence:
    """A message spacing learned online: ``last`` the newest stamp fed (s), ``allow`` how far past it the
    next may be (s): ``k`` x the spacing + the floor, at most ``future_s`` (the floor alone until a first
    sample). The spacing is the median of the last ``_SAMPLES`` block spacings, each the mean spacing of a
    block of messages (2, 4, 8, then ``_BLOCK``): robust to a dropout or a burst (one block), bounded
    memory, a few operations a message, bounded from the third message of a start-up on."""

    __slots__ = ("last", "allow", "n", "due", "mark", "spans", "spacing")

    def __init__(self, floor: float):
        self.last = -math.inf
        self.allow = floor
        self.n = self.due = 1     # messages left in the block being counted, and its length
        self.mark = -math.inf     # the stamp its counting started after
        self.spans: list[float] = []
        self.spacing = 0.0        # s, 0 until a first sample


@dataclass
class _Held:
    items: list[tuple[Message, float]] = field(default_factory=list)  # (message, stamp before correction)
    alive: int = 0  # the guard's on-base count when the first was held
    newest: float = -math.inf  # the stream's newest accepted time when the first was held


class ClockGuard:
    """See the module. ``future_s``: s a stamp may be away from the newest accepted time; ``agree``:
    messages of a sensor that must agree on a new time base before it is taken; ``sensors``: the names
    whose stamps the cadence bound checks (those fed to the filter; 0 ``cadence_k``: none), ``window_s``
    the reorder window (s, the scheduler's ``max_latency``); ``hold_start``: the first messages wait until
    ``agree`` of them lie within ``future_s`` of one another, and one that does not is dropped as a wild
    stamp instead of becoming the stream's time base (at most START_MAX wait; at the end of input,
    ``release`` feeds what still waits)."""

    def __init__(self, future_s: float = 5.0, agree: int = 3, max_gap_s: float = math.inf,
                 cadence_k: float = 0.0, cadence_floor_s: float = 0.02, window_s: float = 0.0, sensors=(),
                 hold_start: bool = False):
        self.max_gap_s = float(max_gap_s)  # a stream-wide jump ahead by more is a clock jump, not a gap
        self._dropped: dict[str, int] = {}   # sensor -> held messages dropped as wild, not yet taken
        self.future_s = float(future_s)
        self.agree = max(1, int(agree))
        self.offsets: dict[str, float] = {}   # sensor -> s subtracted from its stamps
        self._held: dict[str, _Held] = {}
        self._alive = 0                       # messages admitted on the base so far (any sensor)
        self._alive_by: dict[str, int] = {}   # sensor -> _alive when it was last admitted on the base
        self._last_by: dict[str, float] = {}  # sensor -> the (corrected) stamp it was last admitted at
        #: Messages of the compared streams (COMPARED) released by another stream's decision (a pause of the
        #: whole stream): ``(message, t)``, for the pipeline to take (``take_compared``).
        self.compared: list[tuple[Message, float]] = []
        self.busy = False                     # something held or an offset set (the scheduler's fast path)
        self.cadence_k = float(cadence_k)
        self.floor = min(float(cadence_floor_s), self.future_s)
        self.window_s = float(window_s)
        self._cad: dict[str, _Cadence] = {s: _Cadence(self.floor) for s in sensors} if self.cadence_k > 0 else {}
        self._stream_allow = self.floor      # s the stream's newest time may step (its sensors' rates summed)
        self._near: dict[str, tuple[Message, float]] = {}  # sensor -> (message, t) held by the cadence bound
        # Start-up: no time base yet. The first messages wait until ``agree`` of them lie within future_s of
        # one another; one that does not (a wild first stamp) is dropped rather than becoming the base.
        # (``hold_start``: the scheduler's guard does; a guard driven by hand admits its first message.)
        self._start: list[tuple[str, Message, float]] | None = [] if hold_start else None
        self.busy = bool(hold_start)

    def steady(self, sensor: str, t: float, newest: float) -> bool:
        """The scheduler's fast path (nothing held, no offset, no reorder window): True when the message of
        ``sensor`` stamped ``t`` needs no decision (it is noted as fed), False when it must go to ``admit``
        (held, or far: past ``future_s``, which no ``allow`` passes)."""
        c = self._cad.get(sensor)
        if c is None:
            return t <= newest + self.future_s
        d = t - newest
        if d > self.floor and (d > self._stream_allow or t - c.last > c.allow):
            return False
        c.last = t                  # what _fed does, inline: the fast path runs at the input's rate
        c.n -= 1
        if not c.n:
            self._learn(c, t)
        return True

    def admit(self, sensor: str, msg: Message, t: float, newest: float) -> tuple[list[tuple[Message, float]], list[Event]]:
        """Decide about ``msg`` of ``sensor`` stamped ``t`` (s, after its time_offset) given the stream's
        newest accepted time. Returns ``([(message, corrected t), ...], [events])`` in the order to feed
        them (other sensors' messages held by the cadence bound that the stream reached come first); held
        messages that turned out wild are reported by an event and counted (``take_dropped``)."""
        if self._start is not None and sensor != "truth" and sensor != "reference":
            return self._starting(sensor, msg, t)
        c = self._cad.get(sensor)
        if c is None:
            return self._admit(sensor, msg, t, newest, None, [], [])
        out: list[tuple[Message, float]] = []
        events: list[Event] = []
        near = self._near.pop(sensor, None)
        if near is not None:     # this message decides the one held by the cadence bound
            m0, th = near
            if t - self.offsets.get(sensor, 0.0) < th:
                events.append(self._wild(sensor, m0, th, t))
            else:
                out.append((m0, th))
                self._fed(sensor, c, th)
                newest = max(newest, th)
            self.busy = bool(self._held or self.offsets or self._near)
        out, events = self._admit(sensor, msg, t, newest, c, out, events)
        if self._near and out:
            upto = max(tf for _, tf in out)
            ripe = [s for s, (_, th) in self._near.items() if th <= upto]
            if ripe:             # the stream reached them: released at their own times, first
                caught = [self._near.pop(s) for s in ripe]
                for s, (_, th) in zip(ripe, caught):
                    self._fed(s, self._cad[s], th)
                out = sorted(caught + out, key=lambda mt: mt[1])
                self.busy = bool(self._held or self.offsets or self._near)
        return out, events

    #: Messages the start waits for at most; then they go on as they came (no agreeing group in them).
    START_MAX = 8

    def _starting(self, sensor: str, msg: Message, t: float) -> tuple[list[tuple[Message, float]], list[Event]]:
        start = self._start
        assert start is not None
        start.append((sensor, msg, t))
        fut = self.future_s
        members = [i for i, (_, _, ti) in enumerate(start) if abs(ti - t) <= fut]
        if len(members) < self.agree and len(start) < self.START_MAX:
            return [], []
        self._start = None
        self.busy = bool(self._held or self.offsets or self._near)
        keep = set(members) if len(members) >= self.agree else set(range(len(start)))
        events: list[Event] = []
        for i, (s, m, ti) in enumerate(start):
            if i not in keep:
                self._count_dropped(s, 1)
                events.append(Event(math.nan, "time", s, f"line {m.line}: stamp {ti!r} s is far from the stream's "
                                    f"first messages, which agree on another time; it was dropped"))
        return self._admit_in_order([start[i] for i in sorted(keep)], events)

    def _admit_in_order(self, items: list[tuple[str, Message, float]],
                        events: list[Event]) -> tuple[list[tuple[Message, float]], list[Event]]:
        """``items`` through ``admit`` one after another, the stream's newest time advancing with them."""
        out: list[tuple[Message, float]] = []
        newest = -math.inf
        for s, m, ti in items:
            got, ev = self.admit(s, m, ti, newest)
            out += got
            events += ev
            for _, tf in got:
                newest = max(newest, tf)
        return out, events

    def _admit(self, sensor: str, msg: Message, t: float, newest: float, c: _Cadence | None,
               out: list[tuple[Message, float]], events: list[Event]) -> tuple[list[tuple[Message, float]], list[Event]]:
        off = self.offsets.get(sensor, 0.0)
        tc = t - off
        fut = self.future_s
        if off and newest - fut <= tc < newest:
            # A re-synchronised sensor's offset is only known to within its message spacing: it is kept
            # as small as the stream allows (its messages never land behind the stream's newest time).
            off = self.offsets[sensor] = t - newest
            tc = newest
        if newest == -math.inf or (newest - fut <= tc <= newest + fut):
            if self._held:
                events += self._drop(sensor, f"the next {sensor} message is on the stream's time again")
            if c is not None and newest != -math.inf:
                d = tc - newest - self.window_s
                if d > self.floor and (d > self._stream_allow or tc - c.last > c.allow):
                    self._near[sensor] = (msg, tc)     # off the cadence: its next message decides
                    self.busy = True
                    return out, events
            out.append((msg, tc))
            self._fed(sensor, c, tc)
            return out, events
        held = self._held.get(sensor)
        if held is not None:
            last_t = held.items[-1][1]
            # Messages agree on a new base when each is ahead of the previous by at most future_s; or, when no
            # other stream has said anything since the first was held, when each is ahead of the previous at
            # all: a sensor slower than 1 / future_s alone in the stream (a fix every 8 s) steps on as a pause
            # of the whole stream does; before, each of its messages was dropped as a wild stamp (tester4 #15)
            alone = not self._spoken_since(sensor, held)
            if not (0.0 <= t - last_t <= fut or (alone and t > last_t)):   # the earlier ones were wild
                # alone, the held stamps step forward: those before this message still agree with it, and
                # only the later ones (a wild stamp among the slow sensor's) are dropped
                before = [it for it in held.items if it[1] < t] if alone else []
                if before and len(before) < len(held.items):
                    alive, newest_then = held.alive, held.newest
                    held.items = held.items[len(before):]
                    events += self._drop(sensor, "the message after it is stamped before it")
                    held = self._held[sensor] = _Held(items=before, alive=alive, newest=newest_then)
                else:
                    events += self._drop(sensor, "the messages after it do not agree on a new time")
                    held = None
        if held is None:
            held = self._held[sensor] = _Held(alive=self._alive, newest=newest)
        held.items.append((msg, t))
        self.busy = True
        if len(held.items) < self.agree:
            return out, events
        del self._held[sensor]
        first_t = held.items[0][1]
        new_lo = first_t - off - fut
        # another stream admitted since the first was held, on the old base (not already on the new one)
        others_alive = self._spoken_since(sensor, held, before=new_lo)
        ahead = first_t - off > newest
        if ahead and not others_alive:
            gap = first_t - off - newest
            bounded = f", prediction over it bounded to {self.max_gap_s:g} s" if gap > self.max_gap_s else ""
            events.append(Event(first_t - off, "clock", sensor, f"stream time jumped {gap:+.3f} s (no sensor on the "
                                f"old time); taken as a gap in the recording, the stamps kept{bounded}"))
            mine = [(m, ts - off) for m, ts in held.items]
            for _, tf in mine:
                self._fed(sensor, c, tf)
            others = self._same_base(sensor, new_lo, mine[-1][1] + fut, only_compared=sensor in COMPARED)
            for s2, m2, t2 in others:
                if s2 in COMPARED:
                    self.compared.append((m2, t2))
                else:
                    self._fed(s2, self._cad.get(s2), t2)
            fed = [(m2, t2) for s2, m2, t2 in others if s2 not in COMPARED]
            out += sorted(mine + fed, key=lambda mt: mt[1]) if fed else mine
        else:
            new_off = first_t - held.newest  # the first held message lands where the stream was then
            self.offsets[sensor] = new_off
            events.append(Event(newest, "clock", sensor, f"{sensor} clock jumped {new_off - off:+.3f} s "
                                f"({len(held.items)} messages agree); re-synchronised to the stream's time"))
            resynced = [(m, ts - new_off) for m, ts in held.items]
            for _, tf in resynced:
                self._fed(sensor, c, tf)
            out += resynced
        self.busy = bool(self._held or self.offsets or self._near)
        return out, events

    def _spoken_since(self, sensor: str, held: _Held, before: float = math.inf) -> bool:
        """Another stream than ``sensor`` admitted since ``held``'s first message was held, its last stamp
        before ``before`` (s): on the old base."""
        return any(n > held.alive and self._last_by.get(s, -math.inf) < before
                   for s, n in self._alive_by.items() if s != sensor)

    def _same_base(self, sensor: str, lo: float, hi: float,
                   only_compared: bool = False) -> list[tuple[str, Message, float]]:
        """The messages the other streams hold whose (corrected) stamps all lie on the new base ``[lo, hi]``
        (s) that ``sensor``'s messages just agreed on: released with them, ``(stream, message, t)`` in time
        order. A stream holding anything else keeps it held (its own next messages decide), and so do the
        fed sensors when a compared stream decided (``only_compared``: its caller feeds no sensor; they
        decide on their own next messages, truth on the new base not counting as the old one alive)."""
        got: list[tuple[str, Message, float]] = []
        for s2 in [s for s in self._held if s != sensor and (not only_compared or s in COMPARED)]:
            off2 = self.offsets.get(s2, 0.0)
            items = [(m, t - off2) for m, t in self._held[s2].items]
            if all(lo <= t <= hi for _, t in items):
                del self._held[s2]
                got += [(s2, m, t) for m, t in items]
        got.sort(key=lambda smt: smt[2])
        return got

    def take_compared(self) -> list[tuple[Message, float]]:
        """The compared streams' messages released by another stream's decision (see ``compared``), once."""
        out, self.compared = self.compared, []
        return out

    def _fed(self, sensor: str, c: _Cadence | None, t: float) -> None:
        """``sensor``'s message goes on at ``t``: it is on the base, and its spacing and the stream's learn."""
        self._alive += 1
        self._alive_by[sensor] = self._alive
        self._last_by[sensor] = t
        if c is None:
            return
        if c is not None and t >= c.last:
            c.last = t
            c.n -= 1
            if not c.n:
                self._learn(c, t)

    def _learn(self, c: _Cadence, t: float) -> None:
        """A block of ``c.due`` messages ends at ``t``: a spacing sample, and the next block. The stream's
        spacing is that of the sensors' messages merged, 1 / (the sum of their rates), over the sensors on
        their cadence at ``t`` (one that fell silent no longer counts)."""
        due = c.due
        span = (t - c.mark) / due
        c.mark = t
        if due < _BLOCK:
            c.due = due = 2 * due
        c.n = due
        if span == math.inf:
            return
        spans = c.spans
        spans.append(span)
        if len(spans) > _SAMPLES:
            del spans[0]
        c.spacing = sorted(spans)[len(spans) // 2]
        k, floor, fut = self.cadence_k, self.floor, self.future_s
        allow = k * c.spacing + floor
        c.allow = allow if allow < fut else fut
        rate = 0.0
        for x in self._cad.values():
            if x.spacing > 0.0 and t - x.last <= x.allow:
                rate += 1.0 / x.spacing
        allow = k / rate + floor if rate > 0.0 else floor
        self._stream_allow = allow if allow < fut else fut

    def _wild(self, sensor: str, m: Message, th: float, t_next: float) -> Event:
        self._count_dropped(sensor, 1)
        return Event(math.nan, "time", sensor, f"line {m.line}: stamp {m.t!r} s was ahead of the stream's time and "
                     f"off {sensor}'s cadence; it was dropped (the next {sensor} message, stamped {t_next!r} s, "
                     f"is before it)")

    def on_base(self, sensor: str) -> None:
        """Note a message of ``sensor`` known to be on the base with nothing held and no offset (the
        caller's fast path: what ``admit`` would do then, without its result lists)."""
        self._alive += 1
        self._alive_by[sensor] = self._alive

    def _drop(self, sensor: str, why: str) -> list[Event]:
        held = self._held.pop(sensor, None)
        if held is None:
            return []
        self.busy = bool(self._held or self.offsets or self._near)
        self._count_dropped(sensor, len(held.items))
        m, t = held.items[0]
        n = len(held.items)
        return [Event(math.nan, "time", sensor, f"line {m.line}: stamp {t!r} s is far from the stream's time; "
                      f"{'it was' if n == 1 else f'{n} messages were'} dropped ({why})")]

    def _count_dropped(self, sensor: str, n: int) -> None:
        self._dropped[sensor] = self._dropped.get(sensor, 0) + n

    def take_dropped(self) -> dict[str, int]:
        """``{sensor: n}`` of the held messages dropped as wild stamps since the last call (the run counts them
        malformed: their time is)."""
        out, self._dropped = self._dropped, {}
        return out

    def held(self) -> int:
        return sum(len(h.items) for h in self._held.values()) + len(self._near) + len(self._start or ())

    def flush(self) -> list[Event]:
        """End of input: what is still held far from the stream's time is dropped (never fed)."""
        events: list[Event] = []
        for sensor in list(self._held):
            events += self._drop(sensor, "the input ended before later messages could confirm it")
        return events

    def release(self) -> list[tuple[Message, float]]:
        """End of input: the messages still waiting for the start (fewer than ``agree`` came: as they came),
        then those held by the cadence bound, in time order (nothing contradicted them)."""
        first: list[tuple[Message, float]] = []
        if self._start is not None:
            start, self._start = self._start, None
            first, _ = self._admit_in_order(start, [])
        out = first + sorted(self._near.values(), key=lambda mt: mt[1])
        self._near.clear()
        self.busy = bool(self._held or self.offsets)
        return out
