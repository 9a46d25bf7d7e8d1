"""The examples of docs/writing-plugins.md sections 6-8 run as written: the blocks whose first line is
``# example: PATH`` (a decoder of raw ``$`` payloads, the range model's contract with beacons, a source
that loses its link)."""
import re
import types
from pathlib import Path

import pytest

from fusion import pipeline
from fusion.api import InputError
from fusion.config import SystemSpec, wire
from fusion.logformat import checksum
from fusion.registry import make_plugin_manager

DOC = Path(__file__).resolve().parents[2] / "docs" / "writing-plugins.md"


def examples() -> dict[str, str]:
    out = {}
    for block in re.findall(r"```[a-z]*\n(.*?)```", DOC.read_text(), re.S):
        m = re.match(r"# example: (\S+)\n", block)
        if m:
            out[m.group(1)] = block
    return out


def module(path: str) -> types.ModuleType:
    mod = types.ModuleType(path.replace("/", ".").removesuffix(".py"))
    exec(compile(examples()[path], str(DOC) + ":" + path, "exec"), mod.__dict__)
    return mod


def test_the_docs_have_the_examples():
    assert {"fusion_rng/decoder.py", "tests/test_ranges.py", "fusion_rng/source.py"} <= set(examples())


def test_the_decoder_example_decodes_drops_and_refuses():
    RngDecoder = module("fusion_rng/decoder.py").RngDecoder
    _, reg = make_plugin_manager()
    reg.add(RngDecoder)
    spec = SystemSpec.model_validate({
        "name": "rng", "beacons": {"B1": [0, 0], "B2": [10, 0], "B3": [10, 10]},
        "process": {"type": "pv", "dims": 2, "spectral_density": 0.5},
        "initial": {"mean": {"p": [5, 5], "v": [0, 0]}, "sd": {"p": 2.0, "v": 1.0}}, "filter": "ekf",
        "sensors": {"uwb": {"decoder": "rng", "model": "range", "noise": {"sd": 0.1}}}})
    system = wire(spec, registry=reg)

    def sentence(body, hh=None):
        return f"${body}*{checksum(body) if hh is None else hh}"

    beacons = {"B1": (0, 0), "B2": (10, 0), "B3": (10, 10)}
    lines = []
    for k in range(30):
        name = f"B{k % 3 + 1}"
        bx, by = beacons[name]
        lines.append(f"{0.1 * k:.1f},uwb,{sentence(f'RNG,{name},{((5 - bx) ** 2 + (5 - by) ** 2) ** 0.5:.3f}')}")
    lines += ["3.0,uwb," + sentence("RNG,IDLE"), "3.1,uwb," + sentence("RNG,B1,7.07", hh="00"),
              "3.2,uwb,$RNG,B1,7.07", "3.3,uwb,B1@7.07"]
    result = pipeline.run(system, lines, hooks=False)
    uwb = result.summary["sensors"]["uwb"]
    # 30 ranges used, the keep-alive absorbed, the bad and the missing checksum malformed; the last line
    # never reaches the decoder (the parser refuses 'B1@7.07'), counted malformed all the same
    assert (uwb["used"], uwb["absorbed"], uwb["malformed"]) == (30, 1, 3), uwb
    assert uwb["received"] == uwb["used"] + uwb["absorbed"] + uwb["malformed"]   # the parser's is received too
    assert RngDecoder(RngDecoder.Params(strict=False)).decode(
        pipeline.Message(1.0, "uwb", ("$RNG,B2,4.5",))).values == ("B2", 4.5)


def test_the_range_contract_example_passes():
    module("tests/test_ranges.py").test_range_passes_the_measurement_contract()


def test_the_source_example_ends_its_lines_with_an_input_error_on_a_lost_link():
    ListSource = module("fusion_rng/source.py").ListSource
    ListSource.LISTS["demo"] = [f"{0.1 * k:.1f},uwb,B1,4.0\n" for k in range(10)]
    whole = ListSource.from_url("list://demo")
    assert len(list(whole.lines())) == 10 and whole.params.lost is None
    lost = ListSource.from_url("list://demo?lost=4")
    got = []
    with pytest.raises(InputError, match="list://demo: link lost after 4 lines"):
        for line in lost.lines():
            got.append(line)
    assert len(got) == 4
