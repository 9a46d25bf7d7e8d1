"""Binary junk in a recording (issue 10 item 5): one malformed line wherever it is; a file is refused as
no log only when most of its start is binary, and the message says so."""
import json
from pathlib import Path

import pytest

from fusion.cli import main
from fusion.sources.recording import _PROBE

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "uwb_pv_ukf.yaml"
RECORDING = ROOT / "recordings" / "uwb_route1.log"


def summary_of(tmp_path, data: bytes, name="rec") -> dict:
    log, out = tmp_path / f"{name}.log", tmp_path / f"{name}.json"
    log.write_bytes(data)
    assert main(["run", str(CONFIG), "--input", str(log), "-q", "--summary-json", str(out)]) == 0
    return json.loads(out.read_text())


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return summary_of(tmp_path_factory.mktemp("base"), RECORDING.read_bytes())


def uwb_line_index(lines: list[bytes], offset_at_least: int) -> int:
    """Index of the first uwb line starting at or after byte ``offset_at_least``."""
    pos = 0
    for i, line in enumerate(lines):
        if pos >= offset_at_least and b",uwb," in line:
            return i
        pos += len(line) + 1
    raise AssertionError("recording too short")


@pytest.mark.parametrize("where", [0, 3000, _PROBE + 1000], ids=["first-line", "in-the-probe", "after-the-probe"])
@pytest.mark.parametrize("junk", [b"\x00", b"\xff", b"\xc3(", b"\xed\xa0\x80", b"\x1b[2J"],
                         ids=["NUL", "0xff", "cut-utf8", "surrogate", "escape"])
def test_junk_in_one_line_spoils_only_that_line(tmp_path, base, where, junk):
    lines = RECORDING.read_bytes().split(b"\n")
    assert len(RECORDING.read_bytes()) > _PROBE + 5000
    i = uwb_line_index(lines, where)
    lines[i] = lines[i][:5] + junk + lines[i][5:]
    s = summary_of(tmp_path, b"\n".join(lines))
    uwb, ref = s["sensors"]["uwb"], base["sensors"]["uwb"]
    assert uwb["malformed"] == ref["malformed"] + 1
    assert uwb["received"] == ref["received"]       # the spoilt line is still a uwb message, malformed
    assert ref["used"] - 1 <= uwb["used"] <= ref["used"]


def test_a_noisy_port_record_replays(tmp_path, base):
    """What a --record file of a noisy port holds: junk before the first line and NULs mid-file."""
    text = RECORDING.read_bytes()
    data = b"\x00\x00\xff\xfe\x13\x00garbage\n" + text.replace(b"\n", b"\n\x00", 1)
    s = summary_of(tmp_path, data)
    assert s["sensors"]["uwb"]["used"] >= base["sensors"]["uwb"]["used"] - 1
    assert s["sensors"]["uwb"]["malformed"] + s["sensors"].get("?", {}).get("malformed", 0) >= 1


def lines_with_binary_share(share: float, n: int = 200) -> bytes:
    """n lines, the first ``share`` of them (by bytes, near enough) binary, the rest good uwb lines."""
    good = [line for line in RECORDING.read_bytes().split(b"\n") if b",uwb," in line][:n]
    k = round(share * n)
    bad = [b"\x00\x01" + line[2:] for line in good[:k]]  # same length as a good line
    return b"\n".join(bad + good[k:]) + b"\n"


def test_a_file_mostly_binary_at_its_start_is_refused_and_says_so(tmp_path, capsys):
    log = tmp_path / "blob.log"
    log.write_bytes(lines_with_binary_share(0.6))
    assert main(["run", str(CONFIG), "--input", str(log), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(log) in err
    assert "binary data, not a text log: 60% of its first" in err


def test_a_file_less_than_half_binary_is_replayed(tmp_path):
    s = summary_of(tmp_path, lines_with_binary_share(0.4))
    assert s["sensors"]["uwb"]["used"] > 100
    assert s["sensors"]["uwb"]["malformed"] == 80


def test_latin1_text_is_refused_as_not_utf8_with_the_byte(tmp_path, capsys):
    log = tmp_path / "latin1.log"
    log.write_bytes("0.0,uwb,B1,1.0 # \u00e9t\u00e9\n".encode("latin-1") * 50)
    assert main(["run", str(CONFIG), "--input", str(log), "-q"]) == 2
    err = capsys.readouterr().err
    assert "not UTF-8 text: 100% of its first" in err and "byte 0xe9 at offset 17" in err


def test_utf16_is_refused_with_a_hint(tmp_path, capsys):
    log = tmp_path / "u16.log"
    log.write_bytes(RECORDING.read_text().encode("utf-16"))
    assert main(["run", str(CONFIG), "--input", str(log), "-q"]) == 2
    assert "UTF-16 byte-order mark" in capsys.readouterr().err


def test_a_multibyte_character_cut_by_the_probe_is_not_junk(tmp_path):
    """A comment of 'e-acute' characters across the 64 KiB boundary: not binary anywhere."""
    head = b"# " + "\u00e9".encode() * (_PROBE // 2)   # ends mid-character at the probe's last byte
    s = summary_of(tmp_path, head + b"\n" + RECORDING.read_bytes())
    assert s["sensors"]["uwb"]["malformed"] == 0


def test_an_overlong_line_is_one_malformed_line(tmp_path, base):
    """3 MiB without a newline mid-file (a port sending junk for a while): one malformed line, read in
    pieces (never whole), and the next lines are used."""
    from fusion.sources.recording import MAX_LINE

    lines = RECORDING.read_bytes().split(b"\n")
    i = uwb_line_index(lines, 20_000)
    lines[i] = lines[i] + b"7" * (3 * MAX_LINE)     # digits: a cut piece would parse as a valid range
    s = summary_of(tmp_path, b"\n".join(lines))
    assert s["sensors"]["uwb"]["malformed"] == base["sensors"]["uwb"]["malformed"] + 1
    assert s["sensors"]["uwb"]["used"] == base["sensors"]["uwb"]["used"] - 1


def test_a_line_of_exactly_the_limit_is_whole():
    import io

    from fusion.sources.recording import bounded_lines

    text = "x" * 10 + "\n" + "y" * 11 + "\nz"
    assert list(bounded_lines(io.StringIO(text), limit=10)) == ["x" * 10 + "\n", "y" * 10 + "\uffff\n", "z"]


def test_a_fields_line_without_names_is_ignored(tmp_path, base):
    """'# fields uwb' cut after the sensor would make every uwb line a wrong field count."""
    text = RECORDING.read_bytes().replace(b"# fields uwb beacon range", b"# fields uwb")
    assert b"# fields uwb\n" in text
    assert summary_of(tmp_path, text)["sensors"]["uwb"] == base["sensors"]["uwb"]


def test_a_stray_cr_spoils_only_its_line(tmp_path, base):
    """A CR inside a time stamp: one malformed line, not a line cut in two whose second half has a time
    stamp of its own (here 0.0 s: late)."""
    lines = RECORDING.read_bytes().split(b"\n")
    i = uwb_line_index(lines, 20_000)
    lines[i] = lines[i][:3] + b"\r" + lines[i][3:]
    s = summary_of(tmp_path, b"\n".join(lines))["sensors"]["uwb"]
    ref = base["sensors"]["uwb"]
    assert (s["malformed"], s["late"], s["used"]) == (ref["malformed"] + 1, ref["late"], ref["used"] - 1)


@pytest.mark.parametrize("eol", [b"\r\n", b"\r"], ids=["CRLF", "CR"])
def test_crlf_and_cr_line_ends_replay_the_same(tmp_path, base, eol):
    text = RECORDING.read_bytes().replace(b"\n", eol)
    assert summary_of(tmp_path, text)["sensors"] == base["sensors"]
