"""The sensor table adds up: received = used + rejected + malformed + late + absorbed, where absorbed counts
what a decoder dropped (returned None) and what a solver combined into a fix (fusion.run_stats.ABSORBED).
In the summary JSON for every sensor; the table's column appears only when some sensor has any."""
import io
import json
from pathlib import Path

from rich.console import Console

import fusion.registry
from fusion.api import Decoder, Params
from fusion.cli import main
from fusion.registry import make_plugin_manager
from fusion.report import print_summary

ROOT = Path(__file__).resolve().parents[2]


class EveryOther(Decoder):
    """Drops every other message (returns None for odd ones)."""

    name = "every_other"

    class Params(Params):
        pass

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        self.n = 0

    def decode(self, message):
        self.n += 1
        return None if self.n % 2 == 0 else message


def _adds_up(c):
    return c["received"] == c["used"] + c["rejected"] + c["malformed"] + c["late"] + c["absorbed"]


def test_messages_a_decoder_drops_are_counted_absorbed(tmp_path, monkeypatch, capsys):
    _, reg = make_plugin_manager()
    reg.add(EveryOther)
    monkeypatch.setattr(fusion.registry, "_DEFAULT", reg)
    monkeypatch.setenv("COLUMNS", "200")
    text = (ROOT / "configs" / "uwb_pv_ukf.yaml").read_text()
    config = tmp_path / "c.yaml"
    config.write_text(text.replace("recording: ../", f"recording: {ROOT}/").replace(
        "    model: range ", "    decoder: every_other\n    model: range "))
    out = tmp_path / "s.json"
    assert main(["run", str(config), "--summary-json", str(out), "--no-progress"]) == 0
    uwb = json.loads(out.read_text())["sensors"]["uwb"]
    assert uwb["received"] == 1357 and uwb["absorbed"] == 678 and uwb["used"] == 679 and _adds_up(uwb), uwb
    table = capsys.readouterr().out
    assert "absorbed" in table and "678" in table


def test_ranges_a_solver_combines_into_fixes_are_counted_absorbed(tmp_path):
    out = tmp_path / "s.json"
    assert main(["run", str(ROOT / "configs" / "abps_ins.yaml"), "-q", "--summary-json", str(out)]) == 0
    sensors = json.loads(out.read_text())["sensors"]
    assert all(_adds_up(c) for c in sensors.values()), sensors
    assert sensors["abps"]["absorbed"] > 2 * sensors["abps"]["used"] > 0 and sensors["imu"]["absorbed"] == 0


def _table(sensors):
    buf = io.StringIO()
    print_summary({"config": "c.yaml", "sensors": sensors}, console=Console(file=buf, width=200, color_system=None))
    return buf.getvalue()


def test_the_absorbed_column_is_shown_only_when_some_sensor_has_any():
    row = {"received": 5, "used": 5, "rejected": 0, "malformed": 0, "late": 0}
    assert "absorbed" not in _table({"a": {**row, "absorbed": 0}})
    assert "absorbed" not in _table({"a": row})          # a summary from before the counter
    assert "absorbed" in _table({"a": {**row, "absorbed": 0}, "b": {**row, "used": 2, "absorbed": 3}})


def test_lines_the_parser_refuses_are_received_and_malformed():
    """A line of a known sensor that the log parser refuses (wrong field count, a bad number) is a message of
    that sensor: received and malformed, so the sensor's row still adds up (never malformed only:
    received 49 of 51 lines, or received 0 and malformed 60). Lines of a sensor the config lacks too."""
    from fusion import pipeline
    from fusion.config import load_system

    system = load_system(ROOT / "configs" / "uwb_pv_ukf.yaml")
    lines = (ROOT / "recordings" / "uwb_route1.log").read_text().splitlines()[:300]
    n_uwb = sum(",uwb," in line for line in lines)
    lines += ["15.0,uwb,B1,4.0,B2", "15.01,uwb,B1,4.0,B2,5.0,B3", "15.02,uwb,B1,4x0", "15.03,sonar,1.0,nan"]
    sensors = pipeline.run(system, lines).summary["sensors"]
    uwb = sensors["uwb"]
    assert uwb["received"] == n_uwb + 3 and uwb["malformed"] == 3 and _adds_up(uwb), uwb
    assert sensors["sonar"]["received"] == sensors["sonar"]["malformed"] == 1 and _adds_up(sensors["sonar"])
