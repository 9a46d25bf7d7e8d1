"""A virtual clock for the live feed's tests: ``monotonic()`` is a number the test advances with ``sleep``,
so a lag or a silence is exact and no test waits on, or asserts on, real time."""
from __future__ import annotations

import pytest


class VirtualClock:
    def __init__(self, now: float = 1000.0):
        self.now = now

    def monotonic(self) -> float:
        return self.now

    def sleep(self, dt: float) -> None:
        self.now += dt


@pytest.fixture
def clock(monkeypatch):
    """The feed module's ``time`` replaced by a VirtualClock."""
    import fusion.tui.feed as feed_mod

    c = VirtualClock()
    monkeypatch.setattr(feed_mod, "time", c)
    return c
