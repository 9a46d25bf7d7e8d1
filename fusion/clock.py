"""Time sanity per sensor: wild stamps, clock jumps and restarts (issue 10 item 2).

A stream's time base is the newest accepted time. A message whose stamp (after the sensor's
``time_offset`` and any re-synchronisation) is within ``future_s`` seconds of it, ahead or behind, is on
the base and goes on as usual (a little late is the scheduler's late policy). A stamp farther away is
**held**, never fed and never moving the horizon, until the sensor's next messages decide:

- the next message of the sensor is on the base again: the held stamp was wild (a bit flip, ``1e20``, a
  cut fragment such as ``560000``); it is dropped and counted malformed, with a ``time`` event;
- ``agree`` messages in a row agree on a new base (each ahead of the previous by at most ``future_s``):
  the sensor's clock jumped or restarted. If other sensors kept arriving on the old base meanwhile, or the
  new base is behind (a clock reset to 0), the sensor is **re-synchronised**: an offset maps its stamps
  onto the stream's base (the first held message lands at the newest accepted time when it came) and
  is applied to every later message of it (kept as small as the stream allows, so its messages never
  land behind the newest time); a ``clock`` event says by how much. If nothing arrived on the old base
  and the new one is ahead by at most ``max_gap_s``, the whole stream moved on (a pause): the held
  messages are released at their own times and the scheduler predicts over the gap. A stream-wide jump
  ahead by more than ``max_gap_s`` (the scheduler's ``max_predict_s``, longer than any model is
  predicted over) is taken as every clock jumping together: each sensor is re-synchronised as above.

``admit`` returns the messages to feed now, each with its corrected time, and the events to report.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from fusion.api import Event, Message

__all__ = ["ClockGuard"]


@dataclass
class _Held:
    items: list[tuple[Message, float]] = field(default_factory=list)  # (message, stamp before correction)
    alive: int = 0  # the guard's on-base count when the first was held
    newest: float = -math.inf  # the stream's newest accepted time when the first was held


class ClockGuard:
    """See the module. ``future_s``: s a stamp may be away from the newest accepted time; ``agree``:
    messages of a sensor that must agree on a new time base before it is taken."""

    def __init__(self, future_s: float = 5.0, agree: int = 3, on_drop=None, max_gap_s: float = math.inf):
        self.max_gap_s = float(max_gap_s)  # a stream-wide jump ahead by more is a clock jump, not a gap
        self.on_drop = on_drop  # called (sensor, n) when n held messages are dropped as wild
        self.future_s = float(future_s)
        self.agree = max(1, int(agree))
        self.offsets: dict[str, float] = {}   # sensor -> s subtracted from its stamps
        self._held: dict[str, _Held] = {}
        self._alive = 0                       # messages admitted on the base so far (any sensor)
        self._alive_by: dict[str, int] = {}   # sensor -> _alive when it was last admitted on the base
        self.busy = False                     # something held or an offset set (the scheduler's fast path)

    def admit(self, sensor: str, msg: Message, t: float, newest: float) -> tuple[list[tuple[Message, float]], list[Event]]:
        """Decide about ``msg`` of ``sensor`` stamped ``t`` (s, after its time_offset) given the stream's
        newest accepted time. Returns ``([(message, corrected t), ...], [events])``; held messages that
        turned out wild are reported by an event and counted through ``on_drop``."""
        off = self.offsets.get(sensor, 0.0)
        tc = t - off
        fut = self.future_s
        if off and newest - fut <= tc < newest:
            # A re-synchronised sensor's offset is only known to within its message spacing: it is kept
            # as small as the stream allows (its messages never land behind the stream's newest time).
            off = self.offsets[sensor] = t - newest
            tc = newest
        if newest == -math.inf or (newest - fut <= tc <= newest + fut):
            events = self._drop(sensor, f"the next {sensor} message is on the stream's time again") if self._held else []
            self._alive += 1
            self._alive_by[sensor] = self._alive
            return [(msg, tc)], events
        held = self._held.get(sensor)
        events: list[Event] = []
        if held is not None:
            last_t = held.items[-1][1]
            if not (0.0 <= t - last_t <= fut):  # not the same new base: the earlier ones were wild
                events += self._drop(sensor, "the messages after it do not agree on a new time")
                held = None
        if held is None:
            held = self._held[sensor] = _Held(alive=self._alive, newest=newest)
        held.items.append((msg, t))
        self.busy = True
        if len(held.items) < self.agree:
            return [], events
        del self._held[sensor]
        first_t = held.items[0][1]
        others_alive = any(n > held.alive for s, n in self._alive_by.items() if s != sensor)
        ahead = first_t - off > newest
        if ahead and not others_alive and first_t - off - held.newest <= self.max_gap_s:
            events.append(Event(first_t - off, "clock", sensor, f"stream time jumped {first_t - off - newest:+.3f} s "
                                f"(no sensor on the old time); taken as a gap, prediction over it bounded"))
            out = [(m, ts - off) for m, ts in held.items]
        else:
            new_off = first_t - held.newest  # the first held message lands where the stream was then
            self.offsets[sensor] = new_off
            events.append(Event(newest, "clock", sensor, f"{sensor} clock jumped {new_off - off:+.3f} s "
                                f"({len(held.items)} messages agree); re-synchronised to the stream's time"))
            out = [(m, ts - new_off) for m, ts in held.items]
        self._alive += 1
        self._alive_by[sensor] = self._alive
        self.busy = bool(self._held or self.offsets)
        return out, events

    def on_base(self, sensor: str) -> None:
        """Note a message of ``sensor`` known to be on the base with nothing held and no offset (the
        caller's fast path: what ``admit`` would do then, without its result lists)."""
        self._alive += 1
        self._alive_by[sensor] = self._alive

    def _drop(self, sensor: str, why: str) -> list[Event]:
        held = self._held.pop(sensor, None)
        if held is None:
            return []
        self.busy = bool(self._held or self.offsets)
        if self.on_drop is not None:
            self.on_drop(sensor, len(held.items))
        m, t = held.items[0]
        n = len(held.items)
        return [Event(math.nan, "time", sensor, f"line {m.line}: stamp {t!r} s is far from the stream's time; "
                      f"{'it was' if n == 1 else f'{n} messages were'} dropped ({why})")]

    def held(self) -> int:
        return sum(len(h.items) for h in self._held.values())

    def flush(self) -> list[Event]:
        """End of input: what is still held is dropped (never fed)."""
        events: list[Event] = []
        for sensor in list(self._held):
            events += self._drop(sensor, "the input ended before later messages could confirm it")
        return events
