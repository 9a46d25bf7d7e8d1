"""``--debug`` before or after the subcommand (issue 10 item 8): the error is raised (a traceback)
instead of one line and exit code 2."""
import pytest

from fusion.api import ConfigError
from fusion.cli import main


@pytest.mark.parametrize("argv", [["--debug", "run", "nope.yaml"], ["run", "nope.yaml", "--debug"],
                                  ["run", "--debug", "nope.yaml", "-q"]])
def test_debug_anywhere_raises_with_traceback(tmp_path, argv):
    argv = [str(tmp_path / a) if a == "nope.yaml" else a for a in argv]
    with pytest.raises(ConfigError, match="no such file"):
        main(argv)


def test_without_debug_one_line_and_exit_2(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nope.yaml")]) == 2
    err = capsys.readouterr().err
    assert "no such file" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_validate_debug_prints_the_traceback_and_goes_on(tmp_path, capsys):
    assert main(["validate", str(tmp_path / "a.yaml"), str(tmp_path / "b.yaml"), "--debug"]) == 2
    err = capsys.readouterr().err
    assert err.count("Traceback") == 2 and "a.yaml: no such file" in err and "b.yaml: no such file" in err
