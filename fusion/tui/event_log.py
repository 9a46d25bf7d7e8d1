"""A bounded log of events: rejected measurements, gaps, late and malformed lines (with line numbers)."""
from __future__ import annotations

from collections import deque

from rich.text import Text
from textual.widgets import RichLog

from fusion.tui.snapshot import LoggedEvent

_STYLES = {"rejected": "yellow", "malformed": "magenta", "late": "cyan", "gap": "yellow", "source": "bold red",
           "error": "bold red", "not_positive_definite": "bold red", "warning": "yellow"}


def format_event(ev: LoggedEvent) -> Text:
    """``  12.345 rejected  uwb  NIS 40.1 outside the gate`` (time blank for a line that has none)."""
    t = f"{ev.t:9.3f}" if ev.t == ev.t else " " * 9
    out = Text(t + " ")
    out.append(f"{ev.kind:<10}", style=_STYLES.get(ev.kind, "bold"))
    out.append(f" {ev.sensor or '-':<8} ")
    out.append(ev.detail)
    return out


class EventLog(RichLog):
    """The newest ``max_lines`` events; ``lines_text`` keeps their plain text (for tests and copy)."""

    def __init__(self, max_lines: int = 500, **kwargs) -> None:
        super().__init__(max_lines=max_lines, wrap=False, markup=False, highlight=False, **kwargs)
        self.border_title = "events"
        self.last_seq = 0
        self.lines_text: deque[str] = deque(maxlen=max_lines)

    def show(self, events: tuple[LoggedEvent, ...]) -> None:
        """Append the events not shown yet."""
        for ev in events:
            if ev.seq > self.last_seq:
                text = format_event(ev)
                self.write(text)
                self.lines_text.append(text.plain)
                self.last_seq = ev.seq

    def reset(self) -> None:
        self.clear()
        self.lines_text.clear()
