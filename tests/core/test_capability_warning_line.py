"""A CapabilityWarning (a method one edit away from a capability) reaches the user as one line,
``fusion COMMAND: warning: ...``, once, without Python's source line."""
import textwrap

import numpy as np

import fusion.registry
from fusion.api import MeasurementModel
from fusion.cli import main
from fusion.registry import make_plugin_manager


class NearMiss(MeasurementModel):
    """Height (m): a model whose bind_belief is misspelt."""

    name = "near_miss"
    dim = 1

    def h(self, x):
        return np.asarray(x)[..., :1]

    def bind_belif(self, belief_at):   # misspelt on purpose: ReadsBelief's bind_belief
        pass


def test_a_near_miss_is_one_clean_warning_line_once(tmp_path, monkeypatch, capsys):
    _, reg = make_plugin_manager()
    reg.add(NearMiss)
    monkeypatch.setattr(fusion.registry, "_DEFAULT", reg)
    path = tmp_path / "c.yaml"
    path.write_text(textwrap.dedent("""\
        name: near
        process: {type: pv, dims: 1, spectral_density: 0.1}
        initial: {mean: {p: [0], v: [0]}, sd: {p: 1.0, v: 1.0}}
        filter: ekf
        sensors:
          a: {model: near_miss, noise: {sd: 0.5}}
          b: {model: near_miss, noise: {sd: 0.5}}
        """))
    assert main(["validate", str(path), str(path)]) == 0
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("fusion validate: warning: ") and __file__ in lines[0]
    assert "NearMiss.bind_belif looks like capability member 'bind_belief' (ReadsBelief)" in lines[0]
    assert "config.py" not in captured.err and "build_component" not in captured.err
    assert captured.out.count(": ok: near") == 2
