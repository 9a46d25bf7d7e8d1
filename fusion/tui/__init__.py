"""The live view (``fusion tui``): a Textual app built by ``make_app(config, source)``.

The source (a recording paced by sensor time, or a serial port) runs in a worker thread (``feed.LiveFeed``)
that posts coalescing ``messages.FeedUpdate`` snapshots; the widgets (one a module) render them.
"""
from __future__ import annotations

__all__ = ["make_app"]


def make_app(config_path_or_system, source=None, **options):
    """See fusion.tui.app.make_app (imported lazily: Textual is only needed by the live view)."""
    from fusion.tui.app import make_app as _make_app

    return _make_app(config_path_or_system, source, **options)
