"""Sources and sinks chosen through the registry by scheme, device or suffix; a third party's used from
the CLI (the example package's udp:// source and .tsv sink)."""
from __future__ import annotations

import json
import os
import socket
import threading
import time
from pathlib import Path

import pytest

from fusion.api import ConfigError
from fusion.cli import main
from fusion.registry import make_plugin_manager
from fusion.sources.select import open_sink, sink_class, source_class

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"
RECORDING = ROOT / "recordings" / "example_2d.log"


@pytest.fixture(scope="module")
def registry():
    return make_plugin_manager()[1]


@pytest.mark.parametrize("spec,name", [
    ("-", "recording"), ("walk.log", "recording"), ("no_suffix", "recording"), ("file:///tmp/x.log", "recording"),
    ("loop://", "serial"), ("socket://127.0.0.1:7000", "serial"), ("rfc2217://127.0.0.1:2217", "serial"),
    ("COM3", "serial")])
def test_source_by_scheme_device_or_suffix(registry, spec, name):
    assert source_class(spec, registry).name == name


def test_a_character_device_is_a_serial_port_and_dev_null_is_not(registry):
    master, slave = os.openpty()
    try:
        assert source_class(os.ttyname(slave), registry).name == "serial"
    finally:
        os.close(master)
        os.close(slave)
    assert source_class("/dev/null", registry).name == "recording"


def test_unknown_scheme_and_unconverted_logs_are_exit_2_with_the_known_ones(capsys):
    assert main(["run", str(CONFIG), "--input", "udp://127.0.0.1:9", "-q"]) == 2
    err = capsys.readouterr().err
    assert "no source reads udp://" in err and "loop://" in err and "file://" in err
    assert main(["run", str(CONFIG), "--input", "flight.ulg", "-q"]) == 2
    assert "fusion import flight.ulg" in capsys.readouterr().err


def test_sink_by_suffix_and_unknown_suffix_lists_the_known(registry, tmp_path, capsys):
    assert sink_class("out.csv", registry).name == sink_class("out.JSONL", registry).name == "estimates"
    assert sink_class("-", registry).name == "estimates"
    with pytest.raises(ConfigError, match=r"suffix '\.xyz'; known output suffixes: \.csv, \.jsonl, \.mcap, \.ndjson"):
        sink_class("out.xyz", registry)
    with pytest.raises(ConfigError, match="no suffix"):
        sink_class(str(tmp_path / "out"), registry)
    assert main(["run", str(CONFIG), "-q", "-o", str(tmp_path / "x.parquet")]) == 2
    assert "known output suffixes" in capsys.readouterr().err
    assert not (tmp_path / "x.parquet").exists()


def test_open_sink_writes_through_the_registry(registry, tmp_path):
    from fusion.config import load_system
    from fusion import pipeline

    system = load_system(CONFIG)
    out = tmp_path / "e.jsonl"
    result = pipeline.run(system, system.recording, [open_sink(str(out), system.layout, registry)])
    rows = out.read_text().splitlines()
    assert len(rows) == result.stats.estimates and json.loads(rows[-1])["t"] == result.last.t


def _send(port: int, lines: list[str], ready: threading.Event) -> None:
    ready.wait(10)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for i in range(0, len(lines), 40):
            sock.sendto("".join(lines[i:i + 40]).encode(), ("127.0.0.1", port))
            time.sleep(0.002)
    finally:
        sock.close()


def _free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def test_third_party_source_and_sink_from_the_cli(installed_example, tmp_path):
    """The example package's udp:// source feeds `fusion run`; its .tsv sink writes the track."""
    from fusion_altimeter.udp_source import UdpSource

    lines = RECORDING.read_text().splitlines(True)[:900]
    port = _free_udp_port()
    UdpSource.bound.clear()
    sender = threading.Thread(target=_send, args=(port, lines, UdpSource.bound), daemon=True)
    sender.start()
    out, summary = tmp_path / "track.tsv", tmp_path / "s.json"
    code = main(["run", str(CONFIG), "--input", f"udp://127.0.0.1:{port}?idle=1.0", "-o", str(out), "-q",
                 "--summary-json", str(summary)])
    sender.join(5)
    assert code == 0
    s = json.loads(summary.read_text())
    n_uwb = sum(",uwb," in ln for ln in lines)
    assert s["sensors"]["uwb"]["received"] == n_uwb and s["input"].startswith("udp://")
    rows = out.read_text().splitlines()
    assert rows[0].split("\t") == ["t", "px", "py", "sd_px", "sd_py"]
    assert len(rows) - 1 == s["sensors"]["uwb"]["used"]


def test_a_percent_encoded_file_url_reads_the_file(tmp_path, capsys):
    """RFC 8089: Path.as_uri() writes a space as %20 and UTF-8 as %C3%BC; such a URL taken literally
    would read as 'no such recording'."""
    odd = tmp_path / "with space ü.log"
    odd.write_bytes(RECORDING.read_bytes())
    out = tmp_path / "o.json"
    assert main(["run", str(CONFIG), "--input", odd.as_uri(), "-q", "--summary-json", str(out)]) == 0
    assert json.loads(out.read_text())["sensors"]["uwb"]["used"] > 1000


def test_a_missing_input_is_refused_before_the_run(tmp_path, capsys):
    """One line, exit 2, and no summary or output of a run that never read anything (it was 'the input
    stopped early', with a summary of nothing written)."""
    js, csv = tmp_path / "s.json", tmp_path / "o.csv"
    assert main(["run", str(CONFIG), "--input", str(tmp_path / "nope.log"), "-q", "--summary-json", str(js),
                 "-o", str(csv)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"fusion run: error: {tmp_path / 'nope.log'}: no such recording"]
    assert not js.exists() and not csv.exists() and list(tmp_path.iterdir()) == []
