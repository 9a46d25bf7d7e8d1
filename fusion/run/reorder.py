"""The reorder buffer: messages on the stream's time base held ``window`` seconds and released in time order.

It only holds and releases messages: what a released message does to the belief is the loop's. Messages of
one time are released in the order they came. The buffer holds at most ``capacity`` messages: a window that
spans more (a fast stream and a long window) releases the oldest early (``overfull``), and a message that
comes older than the released ``horizon`` afterwards is late, as any other.
"""
from __future__ import annotations

import heapq
import itertools
import math

from fusion.api import Message

__all__ = ["ReorderBuffer", "BUFFER_MAX"]

#: Messages the buffer holds at most (its memory: a few hundred bytes each).
BUFFER_MAX = 100_000


class ReorderBuffer:
    """``add`` messages stamped ``t`` (s, on the stream's time base); ``pop(until)`` releases the oldest when
    it is stamped at or before ``until``. ``newest``: the latest stamp added (-inf before any); ``horizon``:
    the latest stamp released (a message older than it is late)."""

    __slots__ = ("window", "capacity", "newest", "horizon", "_heap", "_seq")

    def __init__(self, window: float = 0.0, capacity: int | None = None):
        self.window = float(window)
        self.capacity = int(BUFFER_MAX if capacity is None else capacity)
        self.newest = -math.inf
        self.horizon = -math.inf
        self._heap: list[tuple[float, int, Message]] = []
        self._seq = itertools.count()

    def __len__(self) -> int:
        return len(self._heap)

    def late(self, t: float) -> bool:
        """A message stamped ``t`` comes after a later one was released."""
        return t < self.horizon

    def add(self, t: float, msg: Message) -> None:
        heapq.heappush(self._heap, (t, next(self._seq), msg))
        if t > self.newest:
            self.newest = t

    @property
    def due(self) -> float:
        """The stamp up to which messages are released now: the newest less the window (s)."""
        return self.newest - self.window

    @property
    def overfull(self) -> bool:
        return len(self._heap) > self.capacity

    @property
    def oldest(self) -> float:
        """The oldest stamp held (inf when empty)."""
        return self._heap[0][0] if self._heap else math.inf

    def pop(self, until: float) -> Message | None:
        """The oldest message when it is stamped at or before ``until`` (s), else None."""
        heap = self._heap
        if not heap or heap[0][0] > until:
            return None
        msg = heapq.heappop(heap)[2]
        if msg.t > self.horizon:
            self.horizon = msg.t
        return msg

    def passed(self, t: float) -> None:
        """A message stamped ``t`` went on without being held (an empty buffer and no window)."""
        self.horizon = self.newest = t
