"""iter_messages' fast path for the common line (a sensor with '# fields', as many plain numbers): the same
messages, verdicts, error texts and counts as the full parse (fusion.logformat._parse_stripped and the field
checks) for any spelling of the values, time and sensor name."""
from hypothesis import given, settings
from hypothesis import strategies as st

from fusion import logformat
from fusion.api import MalformedMessage
from fusion.logformat import ParsedStream, iter_messages

HEADER = ["# fields imu ax ay az", "# fields rep b r ...", "# fields truth px py", "# fields one v"]


def _read(lines, fast, **kw):
    before, logformat._FAST_PATH = logformat._FAST_PATH, fast
    try:
        state = ParsedStream()
        return list(iter_messages(HEADER + lines, state, **kw)), state
    finally:
        logformat._FAST_PATH = before


def _same(a, b, sa, sb):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        if isinstance(x, MalformedMessage):
            assert isinstance(y, MalformedMessage)
            assert (str(x), x.lineno, x.sensor) == (str(y), y.lineno, y.sensor)
        else:
            assert x.__class__ is y.__class__ and tuple(x) == tuple(y)
            assert [type(v) for v in x.values] == [type(v) for v in y.values]
    assert (sa.malformed, sa.last_error) == (sb.malformed, sb.last_error)


_value = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False, width=64).map(repr),
    st.floats(width=64).map(repr),
    st.integers(-10**20, 10**20).map(str),
    st.sampled_from(["-0", "0.", ".5", "+1.0", "1e3", " 2.0", "2.0 ", "1_0", "nan", "-inf", "1e400", "1.2.3", "-", "",
                     "x", "B1", "$GPGGA", "1*5A", "\u0661\u0662", "0x10", "1\x00", "\ufffd", "1\x1f", "\t3", "9" * 400]),
)
_time = st.one_of(st.floats(min_value=-1e6, max_value=1e6).map(repr),
                  st.sampled_from(["nan", "inf", "", "x", " 1.5", "1e400", "\x001", "0"]))
_sensor = st.sampled_from(["imu", "rep", "truth", "one", "other", " imu", "imu ", "bad name", "", "reference"])


@settings(max_examples=600, deadline=None)
@given(st.lists(st.tuples(_time, _sensor, st.lists(_value, min_size=0, max_size=5)), min_size=1, max_size=8),
       st.sampled_from([None, {"imu", "rep", "one"}]), st.sampled_from([(), ("truth", "reference")]))
def test_fast_path_gives_the_full_parse(rows, known, raw):
    lines = [f"{t},{s}," + ",".join(vals) if vals else f"{t},{s}" for t, s, vals in rows]
    a, sa = _read(lines, True, known_sensors=known, raw_streams=raw)
    b, sb = _read(lines, False, known_sensors=known, raw_streams=raw)
    _same(a, b, sa, sb)


def test_fast_path_reads_plain_lines_and_leaves_the_rest():
    lines = ["0.1,imu,1,2,3", "0.2,imu,1,2", "0.3,imu,1,2,nan", "0.4,one,7", "0.5,rep,B1,2.0,B2,3.0", "0.6,imu,1,2,3*00"]
    a, sa = _read(lines, True)
    b, sb = _read(lines, False)
    _same(a, b, sa, sb)
    assert a[0].values == (1.0, 2.0, 3.0) and a[3].values == (7.0,)
    assert [isinstance(m, MalformedMessage) for m in a] == [False, True, True, False, False, True]
    assert sa.malformed == {"imu": 3}


def test_a_later_fields_line_changes_what_the_fast_path_reads():
    lines = ["0.1,new,1,2", "# fields new a b c", "0.2,new,1,2", "0.3,new,1,2,3", "# fields new a b ...", "0.4,new,1,2,3,4"]
    a, sa = _read(lines, True)
    b, sb = _read(lines, False)
    _same(a, b, sa, sb)
    assert [isinstance(m, MalformedMessage) for m in a] == [False, True, False, False]
