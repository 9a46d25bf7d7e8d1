"""The input samples released and not yet integrated: the one place they wait, in time order, until the belief
is needed (a measurement, an output tick, the end of the input, a full run of samples)."""
from __future__ import annotations

import bisect

from fusion.api import Message

__all__ = ["PendingInputs"]


def _msg_t(msg: Message) -> float:
    return msg.t


class PendingInputs:
    """Input messages in time order. ``take(until)`` hands out those stamped at or before ``until`` (s), all when
    ``until`` is None or later than the last; the others stay."""

    __slots__ = ("_items",)

    def __init__(self) -> None:
        self._items: list[Message] = []

    def __len__(self) -> int:
        return len(self._items)

    def __bool__(self) -> bool:
        return bool(self._items)

    def add(self, msg: Message) -> None:
        self._items.append(msg)

    @property
    def last_t(self) -> float | None:
        """The stamp of the latest sample waiting (None when none waits)."""
        return self._items[-1].t if self._items else None

    def take(self, until: float | None = None) -> list[Message]:
        items = self._items
        if until is not None and items and items[-1].t > until:
            k = bisect.bisect_right(items, until, key=_msg_t)
            self._items = items[k:]
            return items[:k]
        self._items = []
        return items
