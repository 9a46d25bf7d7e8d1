"""`fusion run` with a plugin that observes the run badly: a hook or a
plugin's sink that raises, a hook that prints, a source that yields bytes; and the command line's repeated
or clashing options."""
import csv
import io
import json
from pathlib import Path

import pytest

import fusion.registry as registry_module
from fusion import hookimpl
from fusion.api import Params, Source
from fusion.cli import build_parser, main
from fusion.registry import make_plugin_manager

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"


@pytest.fixture
def with_plugin(monkeypatch):
    """Install ``plugin`` (an object with hook implementations) as if it were an installed package's."""
    def install(plugin):
        _, registry = make_plugin_manager(extra_plugins=[plugin])
        monkeypatch.setattr(registry_module, "_DEFAULT", registry)
    return install


def test_a_run_end_hook_that_raises_keeps_the_summary_and_exits_2(tmp_path, capsys, with_plugin):
    """Exit 2 and the --summary-json written after a complete run, not an internal error, exit 1."""
    class Uploader:
        @hookimpl
        def fusion_on_run_end(self, summary):
            raise RuntimeError("upload failed")

    with_plugin(Uploader())
    out, js = tmp_path / "e.csv", tmp_path / "s.json"
    assert main(["run", str(CONFIG), "-q", "-o", str(out), "--summary-json", str(js)]) == 2
    err = capsys.readouterr().err
    assert "internal error" not in err
    assert "fusion run: error: plugin " in err and "Uploader: its fusion_on_run_end hook raised RuntimeError: " \
        "upload failed at the end of the run" in err, err
    summary = json.loads(js.read_text())
    assert len(list(csv.reader(out.open()))) == summary["steps"]["update"] + 1 > 2000    # complete
    assert summary["plugin_errors"] == [line.removeprefix("fusion run: error: ") for line in err.splitlines()
                                        if line.startswith("fusion run: error: plugin")]


def test_a_hook_that_prints_does_not_go_into_the_csv_on_stdout(capsys, with_plugin):
    """`fusion run -o -` with a hook printing a debug line: the CSV holds only its rows."""
    class Chatty:
        @hookimpl
        def fusion_on_estimate(self, estimate):
            print("HOOK EST", estimate.t)

    with_plugin(Chatty())
    assert main(["run", str(CONFIG), "-q", "-o", "-"]) == 0
    out, err = capsys.readouterr()
    rows = list(csv.reader(io.StringIO(out)))
    assert rows[0][0] == "t" and all(len(r) == len(rows[0]) for r in rows) and len(rows) > 2000
    assert err.count("HOOK EST") == len(rows) - 1        # the prints are on stderr, none lost
    import sys
    assert sys.stdout is not sys.stderr                    # restored after the command


def test_without_an_output_on_stdout_a_print_stays_on_stdout(capsys, with_plugin):
    class Chatty:
        @hookimpl
        def fusion_on_run_end(self):
            print("RUN END")

    with_plugin(Chatty())
    assert main(["run", str(CONFIG), "-q"]) == 0
    assert "RUN END" in capsys.readouterr().out


class BytesSource(Source):
    """``bytes://N``: N lines of the example recording as bytes (the source's bug), or an int."""
    name = "bytes_src"
    schemes = ("bytes", "ints")

    class Params(Params):
        count: int = 3
        ints: bool = False

    @classmethod
    def from_url(cls, url, **options):
        return cls(cls.Params(count=int(url.split("://")[1]), ints=url.startswith("ints")))

    def lines(self):
        for line in (ROOT / "recordings" / "example_2d.log").read_text().splitlines()[:self.params.count]:
            yield 42 if self.params.ints else line.encode()


class Sources:
    @hookimpl
    def fusion_register_components(self, registry):
        registry.add(BytesSource)


@pytest.mark.parametrize("url, what", [("bytes://5", "bytes b'"), ("ints://5", "int 42")])
def test_a_source_yielding_non_text_is_named_exit_2(url, what, tmp_path, capsys, with_plugin):
    """Not an internal error (`a bytes-like object is required`), exit 1: the source is named, by the URL
    typed rather than its first parameter's value ('5')."""
    with_plugin(Sources())
    js = tmp_path / "s.json"
    assert main(["run", str(CONFIG), "-q", "--input", url, "--summary-json", str(js)]) == 2
    err = capsys.readouterr().err
    assert "internal error" not in err
    assert f"source 'bytes_src' ({url}) yielded {what}" in err and "as line 1" in err, err
    assert js.is_file()


@pytest.mark.parametrize("option", ["--output", "--plot", "--filter", "--summary-json", "--input"])
def test_an_option_given_twice_is_refused(option, tmp_path, capsys):
    """Not the last kept and the first request dropped without a word: exit 2."""
    values = {"--plot": ("a.png", "b.png"), "--filter": ("ukf", "ekf")}.get(option, ("a.csv", "b.csv"))
    with pytest.raises(SystemExit) as stop:
        main(["run", str(CONFIG), option, str(tmp_path / values[0]) if "." in values[0] else values[0],
              option, str(tmp_path / values[1]) if "." in values[1] else values[1]])
    assert stop.value.code == 2
    assert "given twice" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_csv_and_json_both_on_stdout_are_refused(capsys):
    """`-o - --summary-json -` would put the CSV followed by the JSON on stdout: exit 2."""
    assert main(["run", str(CONFIG), "-o", "-", "--summary-json", "-"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and "--summary-json -: standard output already carries --output" in err


def test_a_negative_number_in_scientific_notation_is_a_value():
    """`--start -1e308` is a value, not an option (`expected one argument`)."""
    args = build_parser().parse_args(["import", "x.ulg", "-o", "x.log", "--start", "-1e308"])
    assert args.start == -1e308
    assert build_parser().parse_args(["tui", "c.yaml", "--speed", "-1E-3"]).speed == -1e-3


def test_a_sweep_with_a_filter_twice_is_refused(tmp_path, capsys):
    """`--filter ukf,ukf` is refused (it would run 4 trials and write 2)."""
    assert main(["sweep", str(CONFIG), "--seeds", "2", "--filter", "ukf,ukf", "-o", str(tmp_path / "r.csv")]) == 2
    assert "ukf given twice" in capsys.readouterr().err and not (tmp_path / "r.csv").exists()
