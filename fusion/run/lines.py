"""The lines a run reads: of a path, a Source or an iterable of text (:func:`lines_of`), a plugin's source's
checked to be text (:func:`source_text`), and a source's own failure told apart from a component's
(:class:`SourceLost`, :func:`guarded`, :func:`source_message`)."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

from fusion.api import Closes, FusionError, InputError, Opens, Source, has
from fusion.run.observers import is_own

__all__ = ["lines_of", "source_text", "SourceLost", "guarded", "source_message"]


def lines_of(source: Any, given: str | None = None) -> tuple[Iterable[str], str, Callable[[], Any] | None]:
    """(lines, label, close) of a path, a Source or an iterable of text lines. A source without a ``label`` of
    its own is named by ``given`` (the text the user typed, ``gen://5``) rather than by the default label, its
    first parameter's value (tester6 #14: "5.0"). A plugin's source's lines are checked to be text."""
    if isinstance(source, (str, Path)):
        from fusion.sources.select import open_source

        source = open_source(str(source))
    if isinstance(source, Source):
        if has(source, Opens):
            source.open()
        if given and type(source).label is Source.label:
            label = given
        else:
            label = source.label or str(getattr(source.params, "path", "") or source.name)
        label = str(label)
        return source_text(source.lines(), source, label), label, source.close if has(source, Closes) else None
    return source, "<lines>", None


def source_text(lines: Iterable[Any], source: Source, label: str) -> Iterable[str]:
    """A plugin's source's ``lines()`` checked to be text: one that yields bytes or anything else (a socket's
    datagrams undecoded) ends the input with an InputError naming the source and what it yielded, where the
    parser would fail on it as an internal error (tester6 #14). fusion's own sources are not re-checked."""
    if is_own(source):
        return lines
    return text_only(lines, source, label)


def text_only(lines: Iterable[Any], source: Source, label: str) -> Iterator[str]:
    for n, line in enumerate(lines, 1):
        if not isinstance(line, str):
            what = type(line).__name__
            hint = " (decode it: line.decode('utf-8'))" if isinstance(line, (bytes, bytearray)) else ""
            raise InputError(f"source {source.name!r} ({label}) yielded {what} {_short(line)} as line {n}: a "
                             f"source's lines() yields text (str){hint}")
        yield line


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


class SourceLost(Exception):
    """The source's own iteration raised (``__cause__``): a lost link, a vanished file, a source's
    InputError. Told apart from a component's failure, which the same loop would otherwise see."""


def guarded(lines: Iterable[str]) -> Iterator[str]:
    try:
        yield from lines
    except (OSError, FusionError) as exc:
        raise SourceLost(str(exc)) from exc


def source_message(name: str, exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        text = exc.strerror + (f": {exc.filename}" if exc.filename else "")
    else:
        text = str(exc) or type(exc).__name__
    return text if name and name in text else f"{name}: {text}"
