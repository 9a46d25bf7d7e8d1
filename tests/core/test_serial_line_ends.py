"""A live serial stream is split into lines as the recording reader splits the same bytes in a file: CR,
CRLF and LF line ends (a device ending lines with CR alone is fused live as its --record file is
replayed), whatever the reads' chunking; an over-long line is one
malformed line, as in a file."""
import os
import threading
import time
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fusion import pipeline
from fusion.config import load_system
from fusion.logformat import OVERLONG
from fusion.sources.line_splitter import PROBE, LineSplitter
from fusion.sources.recording import open_lines

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "uwb_pv_ukf.yaml"
RECORDING = ROOT / "recordings" / "uwb_route1.log"


def live_lines(data: bytes, cuts=(), limit: int = 1 << 20) -> list[str]:
    split = LineSplitter(limit)
    out, start = [], 0
    for cut in sorted(set(cuts)) + [len(data)]:
        out += split.feed(data[start:cut])
        start = cut
    rest = split.end()
    return out + ([rest] if rest is not None else [])


def file_lines(tmp_path: Path, data: bytes) -> list[str]:
    path = tmp_path / "rec.log"
    path.write_bytes(data)
    return list(open_lines(path))


def same(a: list[str], b: list[str]) -> bool:
    """Equal as the parser reads them (each line stripped, blank lines skipped)."""
    return [x.strip() for x in a if x.strip()] == [x.strip() for x in b if x.strip()]


TEXT = "".join(RECORDING.read_text().splitlines(True)[:300])


@pytest.mark.parametrize("eol", ["\n", "\r\n", "\r"])
def test_each_line_end_splits_as_the_file_reader_does(tmp_path, eol):
    data = TEXT.replace("\n", eol).encode()
    live = live_lines(data, cuts=range(7, len(data), 61))   # lines (and CRLFs) cut across reads
    assert same(live, file_lines(tmp_path, data))
    assert len([x for x in live if x.strip()]) == TEXT.count("\n")


@settings(max_examples=60, deadline=None)
@given(st.lists(st.sampled_from(["1.0,uwb,B1,2.5", "# c", "", "x\ry", "\r", "\n", "\r\n", "2.0,uwb,B2,3"]),
                max_size=40),
       st.lists(st.integers(0, 400), max_size=12))
def test_any_mix_and_chunking_gives_the_file_readers_lines(tmp_path_factory, parts, cuts):
    """Lines before the first LF of a stream that has both kinds are the one documented difference: the
    stream here starts with an LF-ended line, or has no LF at all."""
    body = "".join(parts)
    data = ("0.5,uwb,B1,1\n" + body if "\n" in body else body).encode()
    assert same(live_lines(data, cuts), file_lines(tmp_path_factory.mktemp("f"), data) if data.strip() else [])


def test_a_crlf_cut_between_reads_decides_lf_mode(tmp_path):
    """The CR ends the first line, the LF (next read) is the stream's first: from then on LF only."""
    split = LineSplitter()
    assert split.feed(b"1.0,uwb,B1,2\r") == ["1.0,uwb,B1,2\n"]
    assert split.feed(b"\n2.0,uwb,B1,3\rjunk\r\n") == ["2.0,uwb,B1,3\rjunk\r\n"] and split.mode == "lf"


def test_a_stream_without_lf_stays_cr_split_after_the_probe(tmp_path):
    data = ("1.0,uwb,B1,2.5\r" * (PROBE // 10)).encode() + b"2.0,uwb,B2,3\n3.0,uwb,B1,1\r"
    assert same(live_lines(data, range(0, len(data), 4096)), file_lines(tmp_path, data))


@pytest.mark.parametrize("eol", [b"\n", b"\r"])
def test_an_overlong_line_is_one_malformed_line(eol):
    split = LineSplitter(limit=100)
    lines = split.feed(b"1.0,uwb,B1,2" + eol) + split.feed(b"z" * 150) + split.feed(b"z" * 50 + eol + b"2.0,uwb,B1,3" + eol)
    assert [x.strip() for x in lines] == ["1.0,uwb,B1,2", "z" * 100 + OVERLONG, "2.0,uwb,B1,3"]
    assert split.overlong == 1


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="a pty")
@pytest.mark.parametrize("eol", ["\r", "\r\n"])
def test_a_cr_device_over_a_pty_is_fused_and_its_record_replays_identically(tmp_path, eol):
    import tty

    from fusion.sources.serial import SerialSource

    data = TEXT.replace("\n", eol).encode()
    master, slave = os.openpty()
    tty.setraw(slave)
    record = tmp_path / "rec.log"
    src = SerialSource(port=os.ttyname(slave), record=str(record), timeout=0.05)

    def device():
        time.sleep(0.3)   # the port is open and read before the first byte: no line cut by the open
        for i in range(0, len(data), 500):
            os.write(master, data[i:i + 500])
        time.sleep(0.3)
        os.close(master)

    th = threading.Thread(target=device)
    th.start()
    live = pipeline.run(load_system(CONFIG), src)
    th.join()
    os.close(slave)
    assert record.read_bytes() == data
    replay = pipeline.run(load_system(CONFIG), str(record))
    uwb = live.summary["sensors"]["uwb"]
    assert uwb["received"] == uwb["used"] > 0 and not live.parsed.malformed
    assert uwb == replay.summary["sensors"]["uwb"]
    assert (live.last.belief.x == replay.last.belief.x).all()
