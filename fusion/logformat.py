"""The log format (recordings and the serial wire are the same format), DESIGN.md "Log format".

One message a line, UTF-8: ``t,sensor,v1,v2,...`` with an optional ``*HH`` checksum (XOR of the bytes
before ``*``, as NMEA). ``#`` lines are comments and metadata; ``# fields SENSOR NAME NAME`` names a
sensor's columns, and a literal ``...`` after the names makes them a group that repeats on a line
(``# fields uwb beacon range ...``: ``t,uwb,B1,4.2,B3,7.9``, one or more pairs); ``# key: value`` lines
are header metadata (``# scenario: uwb_route1``). A raw NMEA sentence may follow the prefix:
``t,gps,$GPGGA,...*HH`` (the checksum is then the sentence's own and is checked by the ``nmea`` decoder).

Fields parse as float when they look numeric; tokens that start with a letter or ``$`` are labels (a
beacon name) kept as strings. ``nan``/``inf`` and anything else that is neither is malformed, and so is
a line holding binary junk (a NUL or another control character, or U+FFFD where a byte was not UTF-8).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Callable, Collection, Iterable, Iterator, Sequence

from fusion.api import MalformedMessage, Message

_LABEL = re.compile(r"^[A-Za-z_][A-Za-z0-9_.:\-/]*$")
_NONFINITE = {"nan", "+nan", "-nan", "inf", "+inf", "-inf", "infinity", "+infinity", "-infinity"}
_CHECKSUM = re.compile(r"\*([0-9A-Fa-f]{2})$")
_PASS_THROUGH_CHECKSUM = re.compile(r"\*[0-9A-Fa-f]{2}\*([0-9A-Fa-f]{2})$")   # $...*HH (sentence) *HH (line)
_SENSOR = re.compile(r"^[A-Za-z_][A-Za-z0-9_.\-]*$")


def checksum(body: str) -> str:
    """Two hex digits: XOR of the bytes of ``body`` (the text before ``*``)."""
    c = 0
    for b in body.encode("utf-8"):
        c ^= b
    return f"{c:02X}"


def _shown(text: str, most: int = 40) -> str:
    """``text`` quoted for a message, cut to ``most`` characters with its length said, so that a 1 MiB
    field does not make a 1 MiB line on stderr."""
    text = text.strip()
    if len(text) <= most:
        return repr(text)
    return f"{text[:most]!r}... ({len(text)} characters)"


def _field(tok: str) -> float | str:
    try:
        v = float(tok)
    except ValueError:
        tok = tok.strip()
        if tok.lower() not in _NONFINITE and _LABEL.match(tok):
            return tok
        # read before any decoder: say so, and what the line would need for a decoder to see it
        raise MalformedMessage(f"bad number {_shown(tok)} (fields are numbers or labels: a letter or _, then letters, "
                               "digits, _ . : - /; read before any decoder, which gets the raw text only when "
                               "the values start with '$')") from None
    if v - v != 0.0:  # nan or inf (cheaper than math.isfinite on the hot path)
        raise MalformedMessage(f"non-finite value {_shown(tok)}")
    return v


@dataclass
class Header:
    """Metadata collected from ``#`` lines: ``fields`` per sensor and ``key: value`` pairs."""

    fields: dict[str, tuple[str, ...]] = field(default_factory=dict)
    meta: dict[str, str] = field(default_factory=dict)
    repeating: set[str] = field(default_factory=set)  # sensors whose fields repeat as a group (``...``)
    beacons: dict[str, tuple[float, ...]] = field(default_factory=dict)  # '# beacon B1: x y z' (fusion simulate)


def parse_comment(text: str, header: Header) -> None:
    """Record the metadata of one ``#`` line (anything else is a plain comment)."""
    body = text[1:].strip()
    if body.startswith("fields "):
        parts = body.split()
        if len(parts) >= 3:  # '# fields SENSOR' without names says nothing (a cut line): ignored
            names = parts[2:]
            if len(names) > 1 and names[-1] == "...":
                names = names[:-1]
                header.repeating.add(parts[1])
            else:
                header.repeating.discard(parts[1])
            header.fields[parts[1]] = tuple(names)
        return
    if body.startswith("beacon "):
        b = _BEACON.match(body)
        if b:
            try:
                header.beacons[b.group(1)] = tuple(float(v) for v in b.group(2).split())
            except ValueError:
                pass
            return
    m = re.match(r"^([A-Za-z_][A-Za-z0-9_\-]*)\s*:\s*(.*)$", body)
    if m:
        header.meta[m.group(1)] = m.group(2)


_BEACON = re.compile(r"^beacon\s+([A-Za-z_][A-Za-z0-9_.\-]*)\s*:\s*(.*)$")


def read_header(lines: Iterable[str], max_lines: int = 10_000) -> Header:
    """The metadata of the ``#`` lines before the first message (at most ``max_lines`` lines read)."""
    header = Header()
    for n, raw in enumerate(lines):
        text = raw.strip().lstrip("\ufeff")
        if not text:
            continue
        if not text.startswith("#") or n >= max_lines:
            break
        parse_comment(text, header)
    return header


_GOOD_SENSORS: set[str] = set()  # names already checked against _SENSOR (the regex is not run again on every line)


def parse_line(text: str, lineno: int | None = None) -> Message:
    """Parse one message line (not a comment, not blank). Raises MalformedMessage with the reason."""
    return _parse_stripped(text.strip(), lineno)


#: Ends a line a source cut because it was too long (fusion.sources.recording.bounded_lines): a
#: noncharacter, never in text, so the line is malformed rather than a shorter line that parses.
OVERLONG = "\uffff"
_BINARY = re.compile(r"[\x00-\x08\x0e-\x1f\x7f\ufffd\uffff]")  # control characters; U+FFFD: a byte that was not UTF-8


def _parse_stripped(line: str, lineno: int | None, head: list[str] | None = None) -> Message:
    # The hot path of every replay (one call a line): each check below is the cheapest that decides it,
    # and the message is built with tuple.__new__ (NamedTuple's own __new__ is a Python-level frame).
    if "\ufffd" in line or (not line.isprintable() and _BINARY.search(line)):  # isprintable: no regex
        bad = _BINARY.search(line)
        c = bad.group()  # type: ignore[union-attr]
        if c == OVERLONG:
            raise MalformedMessage(f"line longer than {bad.start()} characters (skipped to its end)")  # type: ignore[union-attr]
        what = "invalid UTF-8" if c == "\ufffd" else f"control byte 0x{ord(c):02x}"
        raise MalformedMessage(f"binary data in the line ({what} at column {bad.start() + 1})")  # type: ignore[union-attr]
    if head is None:
        head = line.split(",", 2)
    if len(head) < 3:
        raise MalformedMessage("expected 't,sensor,value,...'")
    t_text, sensor, rest = head
    try:
        t = float(t_text)
    except ValueError:
        raise MalformedMessage(f"bad time {_shown(t_text)}") from None
    if t - t != 0.0:
        raise MalformedMessage(f"non-finite time {_shown(t_text)}")
    if sensor not in _GOOD_SENSORS:
        raw_sensor = sensor
        sensor = sensor.strip()
        if not _SENSOR.match(sensor):
            raise MalformedMessage(f"bad sensor name {_shown(sensor)}")
        if len(_GOOD_SENSORS) < 1000 and sensor == raw_sensor:
            _GOOD_SENSORS.add(sensor)
    if "$" in rest and rest.lstrip()[:1] == "$":
        sentence = rest.strip()
        m = _PASS_THROUGH_CHECKSUM.search(sentence)
        if m:
            # the sentence's own *HH, then the line's (docs/tui.md recommends one on a serial line): the line
            # checksum is checked and stripped, the sentence's left to its decoder (otherwise every GPS
            # line of such a device would be malformed)
            body = line.rstrip()[: -3]
            if checksum(body) != m.group(1).upper():
                raise MalformedMessage(f"bad checksum *{m.group(1)} (computed *{checksum(body)})")
            sentence = sentence[: -3]
        return _new_message(Message, (t, sensor, (sentence,), lineno))
    parts = rest.split(",")
    if "*" in parts[-1]:
        m = _CHECKSUM.search(line)
        if not m:
            raise MalformedMessage(f"bad checksum field {_shown(parts[-1])}")
        body = line[: m.start()]
        if checksum(body) != m.group(1).upper():
            raise MalformedMessage(f"bad checksum *{m.group(1)} (computed *{checksum(body)})")
        parts[-1] = parts[-1][: parts[-1].rindex("*")]
    try:  # fast path: all numbers
        values = tuple(map(float, parts))
    except ValueError:
        if len(parts) == 1 and not parts[0].strip():
            raise MalformedMessage("no values") from None
        return _new_message(Message, (t, sensor, tuple([_field(tok) for tok in parts]), lineno))
    total = sum(values)
    if total - total != 0.0:  # a nan or inf among them (or an overflowing sum: checked one by one)
        return _new_message(Message, (t, sensor, tuple([_field(tok) for tok in parts]), lineno))
    return _new_message(Message, (t, sensor, values, lineno))


_new_message = tuple.__new__


def format_value(v: float | str) -> str:
    """Shortest text that round-trips (repr of a float), labels as they are."""
    if isinstance(v, str):
        return v
    return repr(float(v))


def format_line(t: float, sensor: str, values: Sequence[float | str], with_checksum: bool = False,
                precision: int | None = None) -> str:
    """One log line (no newline). ``precision`` rounds floats to that many decimals (None: exact repr)."""
    if precision is None:
        vals = ",".join(format_value(v) for v in values)
        ts = repr(float(t))
    else:
        vals = ",".join(v if isinstance(v, str) else f"{v:.{precision}f}" for v in values)
        ts = f"{t:.6f}"
    body = f"{ts},{sensor},{vals}"
    return f"{body}*{checksum(body)}" if with_checksum else body


@dataclass
class ParsedStream:
    """Counters of a parsed stream: malformed lines per sensor (``None`` key when the sensor is unknown)."""

    header: Header = field(default_factory=Header)
    malformed: dict[str | None, int] = field(default_factory=dict)
    last_error: dict[str | None, str] = field(default_factory=dict)
    #: Called as ``on_fields(sensor, names, lineno)`` after each ``# fields`` line (a run checks them against
    #: what its components read); it may raise to refuse the stream.
    on_fields: Callable[[str, tuple[str, ...], int], None] | None = None


def _guess_sensor(text: str) -> str | None:
    parts = text.split(",", 2)
    if len(parts) >= 2 and _SENSOR.match(parts[1].strip()):
        return parts[1].strip()
    return None


#: Values text that certainly parses as ``len`` finite floats: plain decimals, at most 15 digits before the
#: point (|v| < 1e15) and 17 after, comma-separated, nothing else (ASCII only). A sufficient test, not a
#: necessary one: any other spelling (an exponent, spaces, a sign +) takes the full parse.
_PLAIN_NUMBERS = re.compile(r"-?[0-9]{1,15}+(?:\.[0-9]{0,17}+)?+(?:,-?[0-9]{1,15}+(?:\.[0-9]{0,17}+)?+)*+")
# (possessive quantifiers, Python 3.11: the numbers cannot overlap, so no backtracking is ever needed, and
# without its bookkeeping the match takes about half the time)


def _raw_message(head: list[str], fields: dict, lineno: int) -> Message | None:
    """A line (split as ``t, sensor, rest``) of a raw stream whose values are certainly ``# fields``-many
    finite numbers, as a Message whose values are still their text (a ``str``), or None (then the line
    takes the full parse, which gives the same verdict and message for anything this does not accept)."""
    names = fields.get(head[1])
    rest = head[2]
    if names is None or rest.count(",") + 1 != len(names) or _PLAIN_NUMBERS.fullmatch(rest) is None:
        return None
    try:
        t = float(head[0])
    except ValueError:
        return None
    if t - t != 0.0:
        return None
    return _new_message(Message, (t, head[1], rest, lineno))


def parse_values(values: tuple | str) -> tuple:
    """A message's values as a tuple: the text of a raw-values message (``iter_messages(raw_streams=...)``)
    parsed to its floats, exactly as the full parse gives them; a tuple as it is."""
    if values.__class__ is str:
        return tuple(map(float, values.split(",")))  # type: ignore[union-attr]
    return values  # type: ignore[return-value]


#: iter_messages reads the common line on its fast path (the tests compare with the full parse alone)
_FAST_PATH = True


def _plain_sensors(header: Header, known: set[str] | None, raw_streams: Collection[str]) -> dict[str, int]:
    """``{sensor: number of fields}`` of the sensors whose lines :func:`iter_messages` may read on its fast
    path: a ``# fields`` line names them (not a repeating group), the name is one the full parse accepts as
    it stands (no spaces to strip), known (when ``known`` is given), not a raw stream."""
    out = {}
    for sensor, names in header.fields.items():
        if (sensor not in header.repeating and names and sensor not in raw_streams and sensor == sensor.strip()
                and _SENSOR.match(sensor) and (known is None or sensor in known or sensor in ("truth", "reference"))):
            out[sensor] = len(names)
    return out


def iter_messages(lines: Iterable[str], state: ParsedStream | None = None,
                  known_sensors: set[str] | None = None,
                  raw_streams: Collection[str] = ()) -> Iterator[Message | MalformedMessage]:
    """Messages from text lines; a malformed line yields a MalformedMessage (with ``.sensor``,
    ``.lineno``) after counting it in ``state``. Comments update ``state.header``. Field counts are
    checked against ``# fields`` when the sensor has them. Never raises on any text.

    ``raw_streams`` (e.g. ``{"truth"}``): a line of these streams that is certainly its ``# fields``-many
    finite numbers is yielded with its values still as text (a ``str``; :func:`parse_values` gives the
    tuple). A truth line arrives at every IMU sample and is interpolated far less often: float() of 16
    values is most of its cost. Every other line of them parses as usual (same verdicts, same errors)."""
    st = state if state is not None else ParsedStream()
    fields = st.header.fields
    plain = _plain_sensors(st.header, known_sensors, raw_streams) if _FAST_PATH else {}
    new = tuple.__new__
    for lineno, raw in enumerate(lines, 1):
        text = raw.strip()
        if not text:
            continue
        if text[0] == "#" or text[0] == "\ufeff":
            text = text.lstrip("\ufeff")
            if text.startswith("#"):
                parse_comment(text, st.header)
                plain = _plain_sensors(st.header, known_sensors, raw_streams) if _FAST_PATH else {}
                if st.on_fields is not None and text[1:].lstrip().startswith("fields "):
                    sensor = text[1:].split()[1] if len(text[1:].split()) > 2 else None
                    if sensor is not None:
                        st.on_fields(sensor, st.header.fields.get(sensor, ()), lineno)
                continue
        head = text.split(",", 2)   # (given to the full parse too: split once)
        if len(head) == 3:
            count = plain.get(head[1])
            if count is not None:
                # The common line, decided here as the full parse decides it: a sensor of known name with
                # '# fields' (not a repeating group), as many values, all of them numbers (float() of each, as
                # the full parse's own fast path), finite, and no binary junk in the line (its first check).
                # Anything else (a checksum, a label, a raw sentence, nan) takes the full parse.
                parts = head[2].split(",")
                if len(parts) == count and "\ufffd" not in text and text.isprintable():
                    try:
                        t = float(head[0])
                        values = tuple(map(float, parts))
                    except ValueError:
                        pass
                    else:
                        total = t + sum(values)
                        if total - total == 0.0:   # all finite (an overflowing sum: the full parse decides)
                            yield new(Message, (t, head[1], values, lineno))
                            continue
            elif raw_streams and head[1] in raw_streams:
                msg = _raw_message(head, fields, lineno)
                if msg is not None:
                    yield msg
                    continue
        try:
            msg = _parse_stripped(text, lineno, head)
            if (known_sensors is not None and msg.sensor not in known_sensors
                    and msg.sensor != "truth" and msg.sensor != "reference"):
                raise MalformedMessage(f"unknown sensor {msg.sensor!r}")
            names = fields.get(msg.sensor)
            if names is not None and len(msg.values) != len(names) and not (
                    len(msg.values) == 1 and isinstance(msg.values[0], str) and msg.values[0].startswith("$")):
                if msg.sensor not in st.header.repeating:
                    raise MalformedMessage(f"{len(msg.values)} values, but '# fields {msg.sensor}' names {len(names)}")
                if not names or len(msg.values) % len(names):
                    raise MalformedMessage(f"{len(msg.values)} values, but '# fields {msg.sensor}' names groups of "
                                           f"{len(names)} ({' '.join(names)} ...)")
        except MalformedMessage as exc:
            sensor = _guess_sensor(text)
            st.malformed[sensor] = st.malformed.get(sensor, 0) + 1
            st.last_error[sensor] = f"line {lineno}: {exc}"
            exc.sensor = sensor  # type: ignore[attr-defined]
            exc.lineno = lineno  # type: ignore[attr-defined]
            yield exc
            continue
        yield msg
