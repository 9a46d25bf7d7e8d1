"""fusion.run.reorder.ReorderBuffer: holds messages for its window, releases them in time order (ties in the
order they came), tells late stamps by the released horizon, and holds at most its capacity."""
import math
import random

from fusion.api import Message
from fusion.run.reorder import ReorderBuffer


def _drain(buf, until):
    out = []
    while (m := buf.pop(until)) is not None:
        out.append(m)
    return out


def test_releases_in_time_order_once_the_window_has_passed():
    rng = random.Random(1)
    msgs = [Message(0.1 * k, "s", (k,)) for k in range(200)]
    arrival = sorted(msgs, key=lambda m: m.t + rng.uniform(0.0, 0.45))   # jitter under the 0.5 s window
    buf = ReorderBuffer(window=0.5)
    released = []
    for m in arrival:
        assert not buf.late(m.t)
        buf.add(m.t, m)
        assert buf.newest == max(x.t for x in arrival[:arrival.index(m) + 1])
        released += _drain(buf, buf.due)
        assert all(r.t <= buf.newest - 0.5 for r in released[-5:])
    released += _drain(buf, math.inf)
    assert released == msgs
    assert buf.horizon == msgs[-1].t and len(buf) == 0


def test_equal_stamps_leave_in_the_order_they_came_and_nothing_early():
    buf = ReorderBuffer(window=1.0)
    a, b, c = Message(2.0, "a", ()), Message(2.0, "b", ()), Message(1.0, "c", ())
    for m in (a, b, c):
        buf.add(m.t, m)
    assert _drain(buf, buf.due) == [c]          # newest 2.0, window 1.0: due 1.0 releases c only
    assert buf.horizon == 1.0
    assert _drain(buf, math.inf) == [a, b]


def test_a_stamp_older_than_the_released_horizon_is_late():
    buf = ReorderBuffer(window=0.0)
    buf.add(1.0, Message(1.0, "s", ()))
    assert _drain(buf, buf.due)[0].t == 1.0
    assert buf.late(0.999) and not buf.late(1.0) and not buf.late(1.5)


def test_the_buffer_tells_when_it_holds_more_than_its_capacity():
    buf = ReorderBuffer(window=1e9, capacity=3)
    for k in range(4):
        buf.add(float(k), Message(float(k), "s", ()))
    assert buf.overfull and buf.oldest == 0.0
    assert buf.pop(buf.oldest).t == 0.0       # the loop releases the oldest early
    assert not buf.overfull and buf.horizon == 0.0 and buf.late(-1.0)


def test_passed_moves_the_horizon_and_the_newest_together():
    buf = ReorderBuffer()
    buf.passed(3.0)
    assert buf.newest == buf.horizon == 3.0 and len(buf) == 0
