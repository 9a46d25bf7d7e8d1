"""User and plugin text is shown as it is, never read as rich markup: a docstring "Height [m]" in
``fusion plugins``, a "[/x]" that would be a markup error, a config path with brackets in the run summary."""
import io
import re
import shutil
from pathlib import Path

import numpy as np
from pydantic import Field
from rich.console import Console

import fusion.registry
from fusion.api import MeasurementModel, Params
from fusion.cli import main
from fusion.registry import make_plugin_manager
from fusion.report import print_summary

ROOT = Path(__file__).resolve().parents[2]
DOC = "Height [m] and rate [m/s], angle [rad], state x[0], set [bold]; [/x] closes nothing."


class BracketParams(Params):
    offset: float = Field(0.0, description="offset [m]")
    axes: list[int] = [0, 1]


class Bracketed(MeasurementModel[BracketParams]):
    __doc__ = DOC
    name = "bracketed"   # a registry name has no brackets (fusion.registry.NAME); its docstring may
    Params = BracketParams
    dim = 1

    def h(self, x):
        return np.asarray(x)[..., :1]


def _registry(monkeypatch):
    _, reg = make_plugin_manager()
    reg.add(Bracketed)
    monkeypatch.setattr(fusion.registry, "_DEFAULT", reg)
    monkeypatch.setenv("COLUMNS", "300")


def test_fusion_plugins_shows_docstrings_with_brackets_as_written(monkeypatch, capsys):
    _registry(monkeypatch)
    assert main(["plugins", "--kind", "measurement"]) == 0
    out = capsys.readouterr().out
    assert DOC in out and "bracketed" in out


def test_fusion_plugins_verbose_shows_names_defaults_and_descriptions_as_written(monkeypatch, capsys):
    _registry(monkeypatch)
    assert main(["plugins", "--kind", "measurement", "--verbose"]) == 0
    out = capsys.readouterr().out
    assert DOC in out and "bracketed" in out and "offset [m]" in out and "[0, 1]" in out


def test_the_summary_shows_paths_names_and_notes_as_written():
    buf = io.StringIO()
    print_summary({"config": "br[red]/c[bold].yaml", "filter": "ekf[2]", "input": "in[/x].log", "duration_s": 1.0,
                   "wall_s": 0.5, "steps": {"predict": 1, "update": 0},
                   "sensors": {"s[1]": {"received": 1, "used": 0, "rejected": 0, "malformed": 1, "late": 0}},
                   "not_started": "no estimate was made: waiting for [bold] (initial.from_sensor)",
                   "info": {"s[1]": {"solver": [1, 2]}}},
                  console=Console(file=buf, width=200, color_system=None))
    out = buf.getvalue()
    for text in ("br[red]/c[bold].yaml", "ekf[2]", "in[/x].log", "s[1]", "waiting for [bold]", "[1, 2]"):
        assert text in out, (text, out)


def test_fusion_run_prints_a_config_path_with_brackets_as_written(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "300")
    folder = tmp_path / "br[red]"
    folder.mkdir()
    config = folder / "c[bold].yaml"
    text = (ROOT / "configs" / "example_2d.yaml").read_text()
    shutil.copy(ROOT / "recordings" / "example_2d.log", folder / "rec[1].log")
    config.write_text(re.sub(r"(?m)^recording: .*$", "recording: rec[1].log", text))
    assert main(["run", str(config), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert f"config       {config}" in out and str(folder / "rec[1].log") in out
