"""The log format: parsing, checksums, metadata, and a property test that the decoder never raises."""
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fusion.api import MalformedMessage, Message
from fusion import logformat
from fusion.logformat import ParsedStream, checksum, format_line, iter_messages, parse_line


def test_parse_numbers_and_labels():
    m = parse_line("1.5,uwb,B2,7.25", 3)
    assert m == Message(1.5, "uwb", ("B2", 7.25), 3)


def test_checksum_matches_nmea_definition():
    # NMEA's published example sentence: body between '$' and '*' XORs to 0x47.
    body = "GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"
    assert checksum(body) == "47"


def test_line_with_good_and_bad_checksum():
    line = format_line(2.0, "imu", [0.1, -9.81, 0.0], with_checksum=True)
    assert parse_line(line).values == (0.1, -9.81, 0.0)
    bad = line[:-2] + ("00" if line[-2:] != "00" else "01")
    with pytest.raises(MalformedMessage, match="checksum"):
        parse_line(bad)


@pytest.mark.parametrize("text,reason", [
    ("abc,imu,1", "bad time"),
    ("1.0,imu,1.2.3", "bad number"),
    ("1.0,imu,nan", "non-finite"),
    ("1.0,imu,inf", "non-finite"),
    ("nan,imu,1", "non-finite time"),
    ("1.0,imu", "expected"),
    ("1.0,i mu,3", "sensor"),
])
def test_malformed_lines_say_why(text, reason):
    with pytest.raises(MalformedMessage, match=reason):
        parse_line(text)


def test_a_bad_field_says_the_decoder_never_saw_it_and_how_a_raw_payload_passes():
    with pytest.raises(MalformedMessage) as exc:
        parse_line("1.0,uwb,B1@23.8d")
    assert str(exc.value) == ("bad number 'B1@23.8d' (fields are numbers or labels: a letter or _, then letters, "
                              "digits, _ . : - /; read before any decoder, which gets the raw text only when the "
                              "values start with '$')")
    # what is accepted is unchanged: labels and numbers split, a '$' payload whole (its checksum unchecked)
    assert parse_line("1.0,uwb,B1:a/b-c,23.8").values == ("B1:a/b-c", 23.8)
    assert parse_line("1.0,uwb,$B1@23.8d,x*00").values == ("$B1@23.8d,x*00",)


def test_nmea_payload_kept_whole():
    m = parse_line("3.0,gps,$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47")
    assert m.values == ("$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47",)


def test_stream_counts_malformed_and_reads_metadata():
    lines = ["# fusion-log 1", "# scenario: demo", "# fields imu ax ay", "0.0,imu,1,2", "0.1,imu,1", "0.2,imu,x!,2",
             "", "0.3,imu,3,4", "garbage"]
    st_ = ParsedStream()
    out = list(iter_messages(lines, st_))
    msgs = [m for m in out if isinstance(m, Message)]
    assert [m.t for m in msgs] == [0.0, 0.3]
    assert st_.header.fields["imu"] == ("ax", "ay")
    assert st_.header.meta["scenario"] == "demo"
    assert st_.malformed == {"imu": 2, None: 1}
    assert "line 6" in st_.last_error["imu"]


def test_format_roundtrip_exact():
    vals = [0.1, 1e-300, -123456.789, 2.0 ** -30]
    m = parse_line(format_line(12.345678901, "s", vals))
    assert m.values == tuple(vals) and m.t == 12.345678901


@settings(max_examples=300, deadline=None)
@given(st.lists(st.text(max_size=60), max_size=20))
def test_decoder_never_raises_on_arbitrary_text(lines):
    for item in iter_messages(lines):
        assert isinstance(item, (Message, MalformedMessage))


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
labels = st.from_regex(r"[A-Za-z][A-Za-z0-9_]{0,6}", fullmatch=True).filter(
    lambda s: s.lower() not in {"nan", "inf", "infinity"})


@settings(max_examples=120, deadline=None)
@given(st.lists(st.tuples(finite, st.sampled_from(["imu", "uwb", "gps_1"]),
                          st.lists(st.one_of(finite, labels), min_size=1, max_size=6), st.booleans()),
                max_size=15),
       st.lists(st.text(max_size=40), max_size=10))
def test_well_formed_lines_are_never_dropped(records, noise):
    """Interleave well-formed lines with arbitrary junk: every well-formed line comes out intact."""
    lines = []
    for i, (t, s, vals, ck) in enumerate(records):
        lines.append(format_line(t, s, vals, with_checksum=ck))
        if i < len(noise):
            junk = noise[i].replace("\n", " ").replace("\r", " ")
            lines.append("# note " + junk)  # comments never swallow a message
    got = [m for m in iter_messages(lines) if isinstance(m, Message)]
    assert len(got) == len(records)
    for m, (t, s, vals, _) in zip(got, records):
        assert m.t == t and m.sensor == s
        assert all((a == b) or (isinstance(a, float) and math.isclose(a, b)) for a, b in zip(m.values, vals))


def test_a_line_checksum_after_a_passed_through_sentence_is_checked_and_stripped():
    """docs/tui.md recommends a line checksum on a serial line; on an NMEA pass-through line it follows the
    sentence's own: '$GPGGA,...*53*21'. Left in, it would make every GPS line malformed."""
    import pynmea2

    nmea = "GPGGA,000000.00,3724.5000,N,12206.0000,W,1,08,0.9,10.0,M,0.0,M,,"
    body = f"12.5,gps,${nmea}*{logformat.checksum(nmea)}"                  # the sentence's own checksum
    sentence = body.split(",", 2)[2]
    m = logformat.parse_line(f"{body}*{logformat.checksum(body)}")
    assert m.values == (sentence,) and pynmea2.parse(m.values[0]).num_sats == "08"
    assert logformat.parse_line(body).values == (sentence,)              # without one: as before
    with pytest.raises(logformat.MalformedMessage, match="bad checksum"):
        logformat.parse_line(body + "*00")


def test_a_huge_bad_field_is_quoted_cut():
    """A 1 MiB number does not make a 1 MiB line on stderr: the message quotes 40 characters and says
    how long the field was."""
    for line, what in ((f"1.0,uwb,B1,{'1' * 1_000_000}", "non-finite value"), (f"1.0,uwb,B1,{'x' * 500}!", "bad number"),
                       (f"{'1' * 100_000},uwb,B1,2", "non-finite time"), (f"{'z' * 100_000},uwb,B1,2", "bad time")):
        with pytest.raises(logformat.MalformedMessage, match=what) as exc:
            logformat.parse_line(line)
        assert len(str(exc.value)) < 300 and "characters)" in str(exc.value)
