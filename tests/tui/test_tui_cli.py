"""`fusion tui` argument handling: every usage/config/input error is one line and exit 2, before the UI."""
from pathlib import Path

import pytest

from fusion.cli import build_parser, main
from fusion.commands.tui import build_app

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "example_2d.yaml"
RECORDING = ROOT / "recordings" / "example_2d.log"


def one_error_line(capsys):
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def test_missing_port_exits_2_with_one_line(capsys):
    assert main(["tui", str(CONFIG), "--port", "/dev/fusion-no-such-port"]) == 2
    line = one_error_line(capsys)
    assert line.startswith("fusion tui: error: cannot open /dev/fusion-no-such-port: No such file or directory")


def test_unknown_port_scheme_names_the_option_given(capsys):
    assert main(["tui", str(CONFIG), "--port", "nosuch://x"]) == 2
    line = one_error_line(capsys)
    assert line.startswith("fusion tui: error: --port nosuch://x: no source reads nosuch://"), line


def test_missing_port_with_record_leaves_no_file(tmp_path, capsys):
    rec = tmp_path / "rec.log"
    assert main(["tui", str(CONFIG), "--port", "/dev/fusion-no-such-port", "--record", str(rec)]) == 2
    one_error_line(capsys)
    assert not rec.exists()


@pytest.mark.parametrize("argv, words", [
    (["--record", "x.log"], "--record tees a live --port"),
    (["--port", "loop://", "--speed", "2"], "--speed applies to replays"),
    (["--speed", "-1"], "--speed -1.0"),
    (["--port", "loop://", "--baud", "0"], "--baud 0"),
    (["--input", "-"], "cannot replay stdin"),
    (["--input", "no/such.log"], "no such recording"),
    (["--filter", "nosuchfilter"], "nosuchfilter"),
])
def test_bad_arguments_exit_2_with_one_line(argv, words, capsys):
    assert main(["tui", str(CONFIG), *argv]) == 2
    assert words in one_error_line(capsys)


def test_record_refuses_to_overwrite(tmp_path, capsys):
    rec = tmp_path / "rec.log"
    rec.write_text("precious\n")
    assert main(["tui", str(CONFIG), "--port", "loop://", "--record", str(rec)]) == 2
    assert "exists" in one_error_line(capsys)
    assert rec.read_text() == "precious\n"


def test_port_and_input_are_exclusive(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["tui", str(CONFIG), "--port", "loop://", "--input", str(RECORDING)])
    assert exc.value.code == 2


def test_arguments_reach_the_app(tmp_path):
    args = build_parser().parse_args(["tui", str(CONFIG), "--input", str(RECORDING), "--speed", "0",
                                      "--filter", "ekf", "--refresh", "10"])
    app = build_app(args)
    assert app.feed.speed == 0.0 and not app.feed.live
    assert app.feed.source.endswith("example_2d.log")
    assert app.system.filter.name == "ekf"
    assert app.feed.refresh_dt == pytest.approx(0.1)
    live = build_app(build_parser().parse_args(["tui", str(CONFIG), "--port", "loop://", "--baud", "9600",
                                                "--record", str(tmp_path / "r.log")]))
    assert live.feed.live and live.feed.source == "loop:// @ 9600 baud"
    live.feed.stop()


def test_default_config_is_used_when_present(monkeypatch, tmp_path):
    from fusion.api import ConfigError
    from fusion.commands import tui

    monkeypatch.chdir(tmp_path)
    (tmp_path / "configs").mkdir()
    (tmp_path / "configs" / "abps_ins.yaml").write_text("name: x\n")
    assert tui._config_path(None) == tmp_path / "configs" / "abps_ins.yaml"
    monkeypatch.setattr(tui, "DEFAULT_CONFIG", Path("configs") / "fusion-none.yaml")
    with pytest.raises(ConfigError, match="no CONFIG given"):
        tui._config_path(None)


def test_default_config_comes_from_the_installed_package_outside_a_checkout(monkeypatch, tmp_path):
    from importlib.resources import files

    from fusion.commands import tui

    monkeypatch.chdir(tmp_path)  # no configs/ here
    found = tui._config_path(None)
    assert found.read_bytes() == (ROOT / "configs" / "abps_ins.yaml").read_bytes()
    assert found == Path(str(files("fusion_configs").joinpath("abps_ins.yaml")))


@pytest.mark.parametrize("argv, words", [
    (["--expect-rate", "uwb"], "--expect-rate uwb: expected SENSOR=HZ"),
    (["--expect-rate", "uwb=-3"], "--expect-rate uwb=-3"),
    (["--limit", "sonar=1"], "--limit sonar=...: no sensor 'sonar' in the config (sensors: uwb)"),
    (["--udp", "localhost"], "--udp localhost: expected HOST:PORT"),
    (["--udp", "127.0.0.1:99999"], "1 to 65535"),
    (["--no-reconnect"], "--no-reconnect applies to a live --port"),
])
def test_bad_live_view_options_exit_2_with_one_line(argv, words, capsys):
    assert main(["tui", str(CONFIG), *argv]) == 2
    assert words in one_error_line(capsys)


def test_a_port_reconnects_unless_asked_not_to():
    app = build_app(build_parser().parse_args(["tui", str(CONFIG), "--port", "loop://"]))
    assert app.feed._close.__self__.params.reconnect is True
    app.feed.stop()
    app = build_app(build_parser().parse_args(["tui", str(CONFIG), "--port", "loop://", "--no-reconnect"]))
    assert app.feed._close.__self__.params.reconnect is False
    app.feed.stop()
