"""Textual messages the data worker posts to the app."""
from __future__ import annotations

from textual.message import Message

from fusion.tui.snapshot import FeedSnapshot


class FeedUpdate(Message):
    """A new snapshot of the feed. Snapshots are cumulative, so a pending one is superseded by a newer one
    (``can_replace``): however fast estimates arrive, the UI renders at most the latest state per turn."""

    def __init__(self, snapshot: FeedSnapshot) -> None:
        super().__init__()
        self.snapshot = snapshot

    def can_replace(self, message: Message) -> bool:
        return isinstance(message, FeedUpdate)
