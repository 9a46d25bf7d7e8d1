"""The live view finishes its run however reading ends: `q` before the input ends (the only
way a live session ends) and a source's lost link (an OSError, as docs/writing-plugins.md section 8 allows)
both call `fusion_on_run_end`; the lost link is a "lost" state (exit 2), as in `fusion run`, not an internal
error."""
from pathlib import Path

from fusion import hookimpl
from fusion.config import load_system
from fusion.registry import make_plugin_manager
from fusion.tui.feed import LiveFeed

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"
LINES = (ROOT / "recordings" / "example_2d.log").read_text().splitlines()


class Ends:
    def __init__(self):
        self.summaries = []

    @hookimpl
    def fusion_on_run_end(self, summary):
        self.summaries.append(summary)


def _system(watcher):
    _, registry = make_plugin_manager(extra_plugins=[watcher])
    return load_system(CONFIG, registry=registry)


def test_q_before_the_end_of_the_input_still_ends_the_run():
    """stop() ('q') does not only close the sinks: fusion_on_run_end is called."""
    watcher = Ends()
    feed = None

    def lines():
        for i, line in enumerate(LINES):
            if i == 300:
                feed.stop()                  # the user presses q mid-replay
            yield line

    feed = LiveFeed(_system(watcher), lines(), lambda s: None, speed=0.0)
    snap = feed.run()
    assert snap.state == "stopped" and feed.done.is_set()
    assert len(watcher.summaries) == 1 and watcher.summaries[0]["interrupted"] is True
    assert feed.result is not None and 0 < feed.result.stats.estimates < 300


def test_a_source_that_loses_its_link_is_lost_not_an_internal_error():
    """Exit 2 as in `fusion run`, not `fusion tui: internal error: OSError: gen link dropped`, exit 1."""
    watcher = Ends()

    def lines():
        yield from LINES[:200]
        raise OSError("gen link dropped")

    feed = LiveFeed(_system(watcher), lines(), lambda s: None, source="gen://20", speed=0.0)
    snap = feed.run()
    assert snap.state == "lost" and snap.message == "gen://20: gen link dropped"
    assert feed.result.source_error == "gen://20: gen link dropped"
    assert len(watcher.summaries) == 1 and watcher.summaries[0]["source_error"] == "gen://20: gen link dropped"
