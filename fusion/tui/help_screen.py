"""The ``?`` help screen: every key of the view, what the panels show, and how to close it."""
from __future__ import annotations

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Static

PANELS = """\
[b]state[/]       each element with its 1-sigma (attitude as roll/pitch/yaw, deg)
[b]sensors[/]     received, used, rejected, malformed, late and the rate (Hz)
[b]health[/]      rate against the expected rate, time since the last accepted measurement
            against its limit, problem counts; filter repairs, resets, clock events;
            the overall OK / DEGRADED / LOST with its reason (also in the status line)
[b]track[/]       top view (east right, north up): estimate, truth, beacons, now (●),
            2-sigma ellipse, true position now (○)
[b]innovations[/] test ratio NIS/gate with the gate at 1 (red x: rejected), and the
            innovation of one element with +-sqrt(S)
[b]events[/]      rejected, late, gap, malformed (line numbers), port lost and back
[b]states[/]      one state element: its error against truth with +-3 sigma, or (no truth)
            its value with +-1 sigma (bias states: how well the bias is known)"""


class HelpScreen(ModalScreen):
    """Lists ``keys`` (key, description) pairs; any of escape, q or ? closes it."""

    DEFAULT_CSS = """
    HelpScreen { align: center middle; }
    HelpScreen > VerticalScroll { width: 90%; max-width: 96; height: 90%; border: round $accent;
                                  background: $surface; padding: 0 1; }
    """
    BINDINGS = [Binding("escape,q,question_mark", "app.pop_screen", "close help")]

    def __init__(self, keys: list[tuple[str, str]]) -> None:
        super().__init__()
        self.keys = keys
        width = max(len(k) for k, _ in keys)
        self.text = "\n".join(f"[b]{k:<{width}}[/]  {d}" for k, d in keys)

    def compose(self) -> ComposeResult:
        with VerticalScroll():
            yield Static("[b]Keys[/]  (escape, q or ? closes this)\n\n" + self.text + "\n\n[b]Panels[/]\n\n" + PANELS)
