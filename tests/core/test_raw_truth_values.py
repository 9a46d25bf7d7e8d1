"""Truth lines read with their values left as text (``iter_messages(raw_streams=...)``, as ``fusion run``
reads them): the same messages, verdicts and errors as the full parse, the values parsed where used."""
import math

from hypothesis import given, settings
from hypothesis import strategies as st

from fusion import pipeline
from fusion.api import MalformedMessage
from fusion.logformat import ParsedStream, iter_messages, parse_values
from fusion.truth_stream import TruthWindow, _median
from fusion.testing.faults import thin_truth

RAW = frozenset(("truth", "reference"))
HEADER = ["# fields truth px py pz", "# fields reference px py pz", "# fields pos x y z"]


def _both(lines):
    full = list(iter_messages(HEADER + lines, ParsedStream()))
    st_raw = ParsedStream()
    raw = list(iter_messages(HEADER + lines, st_raw, raw_streams=RAW))
    return full, raw, st_raw


def _same(full, raw):
    assert len(full) == len(raw)
    for a, b in zip(full, raw):
        if isinstance(a, MalformedMessage):
            assert isinstance(b, MalformedMessage) and str(a) == str(b) and a.lineno == b.lineno
        else:
            assert (a.t, a.sensor, a.line) == (b.t, b.sensor, b.line)
            assert parse_values(b.values) == a.values
            assert b.values.__class__ is tuple or all(type(x) is float for x in a.values)


_number_text = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False, width=64).map(repr),
    st.floats(min_value=-1e16, max_value=1e16, allow_nan=False).map(lambda v: f"{v:.6f}"),
    st.integers(-10**17, 10**17).map(str),
    st.sampled_from(["-0", "0.", "-0.000", ".5", "+1.0", "1e3", " 2.0", "1_0", "nan", "inf", "1.2.3", "-",
                     "", "x", "12345678901234567", "1." + "9" * 18, "\u0661\u0662", "0x10"]),
)


@settings(max_examples=400, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["truth", "reference", "pos"]),
                          st.lists(_number_text, min_size=1, max_size=5)), min_size=1, max_size=8))
def test_raw_reading_gives_the_full_parse_for_any_spelling(rows):
    lines = [f"{0.1 * i:.3f},{s}," + ",".join(vals) for i, (s, vals) in enumerate(rows)]
    full, raw, _ = _both(lines)
    _same(full, raw)


def test_plain_truth_lines_stay_text_and_others_are_parsed():
    full, raw, st_raw = _both(["0.0,truth,1.000000,-2.5,3", "0.0,pos,1,2,3", "0.1,truth,1e3,2,3",
                               "0.2,truth,1,2", "0.3,truth,1,2,nan", "0.4,reference,-0.5,0.25,0"])
    _same(full, raw)
    kinds = [m.values.__class__.__name__ if not isinstance(m, MalformedMessage) else "bad" for m in raw]
    assert kinds == ["str", "tuple", "tuple", "bad", "bad", "str"]
    assert st_raw.malformed == {"truth": 2}


def test_digits_beyond_what_is_surely_finite_take_the_full_parse():
    big = "9" * 400                                    # float() gives inf: malformed, as without raw reading
    full, raw, _ = _both([f"0.0,truth,{big},1,2", "0.1,truth,123456789012345,1,2"])
    _same(full, raw)
    assert isinstance(raw[0], MalformedMessage)
    assert raw[1].values.__class__ is str


def test_window_takes_text_and_tuples_alike_and_interpolates_the_same():
    a, b = TruthWindow(["px", "qw", "qx", "qy", "qz"]), TruthWindow(["px", "qw", "qx", "qy", "qz"])
    rows = [(0.0, "1.0,1,0,0,0"), (0.1, "2.0,0.9,0.1,0,0"), (0.2, "2.5,0.8,0.2,0.1,0")]
    for t, text in rows:
        msg = pipeline.Message(t, "truth", text, 1)
        assert a.add(msg)
        assert b.add(msg._replace(values=parse_values(text)))
    for t in (0.0, 0.05, 0.13, 0.2):
        assert a.row(t).tolist() == b.row(t).tolist()
    assert not a.add(pipeline.Message(0.3, "truth", "1,2", 2)) and a.skipped == 1   # wrong count


def test_run_gives_the_same_comparison_as_parsed_truth(tmp_path):
    """A whole run with raw truth reading equals a run fed the fully parsed messages (Run.push)."""
    from pathlib import Path

    from fusion.config import load_system

    cfg = Path(__file__).resolve().parents[2] / "configs" / "uwb_pv_ukf.yaml"
    lines = load_system(cfg).recording.read_text().splitlines()
    lines = lines[: len(lines) // 4]
    fast = pipeline.run(load_system(cfg), lines)
    session = pipeline.Run(load_system(cfg))
    for item in iter_messages(lines, session.parsed):
        session.push(item)
    slow = session.finish()
    assert fast.summary["errors"] == slow.summary["errors"]
    assert fast.summary["consistency"] == slow.summary["consistency"]
    assert fast.summary["errors"]["samples"] > 100


def test_median_is_numpys():
    import numpy as np

    rng = np.random.default_rng(3)
    for n in range(1, 40):
        v = (rng.standard_normal(n) * 10.0 ** rng.integers(-6, 6, n)).tolist()
        assert _median(v) == float(np.median(v))
    assert math.isclose(_median([1.0, 2.0]), 1.5)


def test_window_rows_normalise_quaternions_as_numpy_does():
    """_Rows normalises each quaternion in plain floats; the same last bit as np.linalg.norm and a divide
    (what fusion.metrics.Truth does over all rows at once)."""
    import numpy as np

    rng = np.random.default_rng(7)
    names = ["px", "qw", "qx", "qy", "qz", "bw"]
    w = TruthWindow(names)
    Q = rng.standard_normal((400, 6)) * rng.choice([1.0, 1e-3, 1e3], (400, 1))
    Q[5, 1:5] = 0.0                                            # a zero quaternion is left as it is
    for i, row in enumerate(Q):
        w.add(pipeline.Message(float(i), "truth", tuple(row.tolist()), i))
    from fusion.truth_stream import _Rows

    rows = _Rows(w._v, w.quaternions)
    for i, row in enumerate(Q):
        q = row[None, 1:5]
        nrm = np.linalg.norm(q, axis=1, keepdims=True)
        want = row.copy()
        want[1:5] = np.divide(q, nrm, out=q.copy(), where=nrm > 0)[0]
        assert rows[i].tolist() == want.tolist()


def test_truth_sparser_than_the_estimates_is_warned_about(tmp_path, capsys):
    """Truth at 1 Hz against estimates at ~20 Hz: the end of the run says the errors between truth samples
    include the interpolation's; at the recording's own truth rate it says nothing."""
    from pathlib import Path

    from fusion.cli import main

    root = Path(__file__).resolve().parents[2]
    out = thin_truth(root / "recordings" / "uwb_route1.log", 0.999)   # truth at 1 Hz
    coarse = tmp_path / "coarse.log"
    coarse.write_text("\n".join(out) + "\n")
    assert main(["run", str(root / "configs" / "uwb_pv_ukf.yaml"), "--input", str(coarse)]) == 0
    err = capsys.readouterr().err
    assert "truth every 1 s, sparser than the estimates" in err and "0.12 m at 1 m/s^2" in err
    assert main(["run", str(root / "configs" / "uwb_pv_ukf.yaml")]) == 0
    assert "sparser" not in capsys.readouterr().err
