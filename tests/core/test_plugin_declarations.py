"""What an installed plugin declares is checked when it registers, and a component that fails while it is
built is named. Refused at registration, as a name registered twice is (the plugin's
other names still work, ``fusion plugins`` lists it as broken, exit 2, and a config using it is exit 2 with
that line): a ``Params`` that is not a fusion.api.Params (a plain pydantic model accepted misspelt keys), a
``Params = None``, a default that is not a valid value of its field, a name that is no identifier (a module
path, a space) or differs from a registered one only in case. A component whose ``__init__`` raises (a
missing calibration file, a RuntimeError): exit 2 naming the config line, the component, its kind and
package, the exception; ``--debug`` shows the traceback. (These were silently accepted, or an internal
error, exit 1.)"""
import os
import subprocess
import sys

import pytest

from fusion.registry import NAME, _check_params, make_plugin_manager, params_default_errors

PLUGIN = '''\
import os
import pydantic
from fusion import hookimpl
from fusion.api import Gate, GateDecision, MeasurementModel, Params, Sink

FAULT = os.environ.get("FAULT", "")


class Alt(MeasurementModel):
    """Height [m]: the state's p_y."""
    name = "alt"
    dim = 1

    def __init__(self, params=None, context=None):
        if FAULT == "init_runtime":
            raise RuntimeError("alt: cannot talk to the sensor")
        if FAULT == "init_missing":
            open("calib.yaml")
        super().__init__(params, context)

    def h(self, x):
        return x[..., 1:2]


class Fussy(Gate):
    """NIS gate at 9 (dimensionless)."""
    name = "fussy"

    def check(self, nis, dim, state):
        if FAULT == "gate_raise":
            raise RuntimeError("gate boom")
        return GateDecision(nis <= 9.0, 9.0), state


class Tab(Sink):
    """Writes nothing to a .tab file."""
    name = "tab"
    suffixes = (".tab",)

    class Params(Params):
        path: str

    def __init__(self, params=None, context=None):
        if FAULT == "sink_init":
            raise RuntimeError("tab: cannot open")
        super().__init__(params, context)


@hookimpl
def fusion_register_components(registry):
    registry.add(Alt)
    registry.add(Fussy)
    registry.add(Tab)
    if FAULT == "params_plain":
        class Plain(Fussy):
            """Plain pydantic parameters."""
            name = "strict"

            class Params(pydantic.BaseModel):
                limit: float = 9.0
        registry.add(Plain)
    if FAULT == "params_default":
        class BadDefault(Fussy):
            """A default of the wrong type."""
            name = "strict"

            class Params(Params):
                limit: float = "nine"
        registry.add(BadDefault)
    if FAULT == "params_none":
        class NoParams(Fussy):
            """No Params."""
            name = "strict"
            Params = None
        registry.add(NoParams)
    if FAULT == "state_raise":
        class Stateful(Fussy):
            """Keeps a state whose start cannot be made."""
            name = "strict"

            class Params(Params):
                limit: float = 9.0

            def initial_state(self):
                raise RuntimeError("no state today")
        registry.add(Stateful)
    if FAULT == "name":
        class Named(Fussy):
            """Named by the environment."""
            name = os.environ["NAME"]
        registry.add(Named)
'''

CONFIG = """\
name: decl
recording: r.log
process: {{type: pv, dims: 2, spectral_density: 0.1}}
initial: {{mean: {{p: [0, 0], v: [0, 0]}}, sd: {{p: 1.0, v: 1.0}}}}
filter: ekf
sensors:
  s: {{model: alt, noise: {{sd: 0.5}}{gate}}}
  q: {{model: position, noise: {{sd: 0.5}}}}
"""
WAY_OUT = "in plugin 'decl' of the installed package 'fusion-decl 0.2'"


@pytest.fixture
def fusion(tmp_path):
    """Run ``fusion ARGS`` with the package fusion-decl 0.2 installed (entry point ``decl``; FAULT picks the
    fault); checks that no traceback and no internal error is printed unless asked (``debug=True``)."""
    site = tmp_path / "site"
    (site / "fusion_decl").mkdir(parents=True)
    (site / "fusion_decl" / "__init__.py").write_text("")
    (site / "fusion_decl" / "plugin.py").write_text(PLUGIN)
    info = site / "fusion_decl-0.2.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: fusion-decl\nVersion: 0.2\n")
    (info / "entry_points.txt").write_text("[fusion]\ndecl = fusion_decl.plugin\n")
    (tmp_path / "plain.yaml").write_text(CONFIG.format(gate=""))
    for gate in ("fussy", "strict"):
        (tmp_path / f"{gate}.yaml").write_text(CONFIG.format(gate=f", gate: {{type: {gate}, limit: 9.0}}"
                                                             if gate == "strict" else f", gate: {gate}"))
    (tmp_path / "r.log").write_text("".join(f"{k / 10:.1f},s,{0.01 * k:.3f}\n{k / 10:.1f},q,0.0,{0.01 * k:.3f}\n"
                                            for k in range(30)))
    env = {k: v for k, v in os.environ.items() if k not in ("FUSION_DISABLE_PLUGIN_AUTOLOAD", "FUSION_BLOCK_PLUGINS")}
    env["PYTHONPATH"] = os.pathsep.join([str(site), env.get("PYTHONPATH", "")])
    env["COLUMNS"] = "400"

    def run(fault, *args, debug=False, **extra):
        cmd = [sys.executable, "-c", "import sys; from fusion.cli import main; sys.exit(main())", *args]
        proc = subprocess.run(cmd, env={**env, "FAULT": fault, **extra}, cwd=tmp_path, capture_output=True, text=True)
        if not debug:
            assert "Traceback" not in proc.stderr and "internal error" not in proc.stderr, proc.stderr
        return proc

    return run


@pytest.mark.parametrize("fault,what", [
    ("params_plain", "gate 'strict': its Params (fusion_register_components.<locals>.Plain.Params) does not derive "
                     "from fusion.api.Params: unknown (misspelt) keys would be accepted silently"),
    ("params_default", "gate 'strict': a default of its Params (fusion_register_components.<locals>.BadDefault.Params) "
                       "is not a valid value: limit = 'nine': Input should be a valid number"),
    ("params_none", "gate 'strict': Params must be a class deriving from fusion.api.Params, got None"),
])
def test_a_params_that_would_lose_or_break_the_config_is_refused_at_registration(fusion, fault, what):
    listed = fusion(fault, "plugins")
    assert listed.returncode == 2 and what in listed.stderr and WAY_OUT in listed.stderr, listed.stderr
    assert "fussy" in listed.stdout and "alt" in listed.stdout            # the plugin's other names work
    used = fusion(fault, "validate", "strict.yaml")
    assert used.returncode == 2 and "strict.yaml:7: sensors.s.gate: " in used.stderr and what in used.stderr
    other = fusion(fault, "run", "fussy.yaml", "-q")
    assert other.returncode == 0 and other.stderr.count("\n") == 1 and "warning" in other.stderr, other.stderr


@pytest.mark.parametrize("name,what", [
    ("fusion_decl.plugin:Gate", "gate name 'fusion_decl.plugin:Gate' is not a registry name"),
    ("my gate", "gate name 'my gate' is not a registry name"),
    ("2nd", "gate name '2nd' is not a registry name"),
    ("CHI2", "gate 'CHI2' differs from the registered gate 'chi2' only in case"),
])
def test_a_name_a_config_cannot_write_or_tell_apart_is_refused(fusion, name, what):
    listed = fusion("name", "plugins", NAME=name)
    assert listed.returncode == 2 and what in listed.stderr and WAY_OUT in listed.stderr, listed.stderr
    assert "plugin.py:" in listed.stderr        # where the plugin registers it


@pytest.mark.parametrize("fault,what", [
    ("init_runtime", "RuntimeError: alt: cannot talk to the sensor"),
    ("init_missing", "FileNotFoundError: [Errno 2] No such file or directory: 'calib.yaml'"),
])
def test_a_component_that_raises_while_built_is_named_with_its_config_line(fusion, fault, what):
    for cmd in ("run", "validate"):
        proc = fusion(fault, cmd, "plain.yaml")
        assert proc.returncode == 2, proc.stderr
        assert (f"plain.yaml:7: sensors.s.model: component 'alt' (measurement, from fusion-decl 0.2) failed to build: "
                f"{what}") in proc.stderr, proc.stderr
    debug = fusion(fault, "run", "plain.yaml", "--debug", debug=True)
    assert debug.returncode != 0 and "Traceback" in debug.stderr and "fusion_decl/plugin.py" in debug.stderr


def test_a_sink_that_raises_while_built_is_named_with_its_output(fusion):
    proc = fusion("sink_init", "run", "plain.yaml", "-q", "-o", "x.tab")
    assert proc.returncode == 2
    assert ("--output x.tab: component 'tab' (sink, from fusion-decl 0.2) failed to build: RuntimeError: tab: cannot "
            "open") in proc.stderr, proc.stderr


def test_a_gate_that_raises_names_its_package_and_the_run_goes_on(fusion):
    proc = fusion("gate_raise", "run", "fussy.yaml", "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert "gate 'fussy' (fusion-decl 0.2) failed in the update: RuntimeError: gate boom" in proc.stdout + proc.stderr


def test_every_built_in_name_and_params_passes_the_checks_third_parties_get():
    """The defaults of built-in Params are not checked at every start (fusion.registry._check_params): here."""
    _, reg = make_plugin_manager()
    for e in reg.entries():
        assert NAME.match(e.name), e
        _check_params(e.kind, e.name, e.cls)
        assert params_default_errors(e.cls.Params) == "", e


def test_a_built_in_components_bug_while_built_is_still_an_internal_error(monkeypatch, tmp_path):
    from fusion.api import BuildContext
    from fusion.config import build_component
    from fusion_plugins.gates.chi2 import Chi2Gate

    def broken(self, params=None, context=None):
        raise RuntimeError("a bug of ours")

    monkeypatch.setattr(Chi2Gate, "__init__", broken)
    _, reg = make_plugin_manager()
    with pytest.raises(RuntimeError, match="a bug of ours"):
        build_component(reg, "gate", "chi2", BuildContext())


def test_params_default_errors_reads_only_plain_defaults():
    from pydantic import Field

    from fusion.api import Params

    class P(Params):
        a: float = "x"
        b: float = None            # "not given": the usual idiom, not checked
        c: list[float] = Field(default_factory=list)
        d: int

    why = params_default_errors(P)
    assert why.startswith("a = 'x': ") and ";" not in why     # only a: b, c and d are not checked


def test_a_gate_whose_initial_state_raises_is_named_with_its_config_line(fusion):
    """A stateful gate whose initial_state() raises is not an exception out of the run (exit 1) but
    one config error at wiring, as a component that fails while built, from validate and run alike."""
    for cmd in ("validate", "run"):
        proc = fusion("state_raise", cmd, "strict.yaml")
        assert proc.returncode == 2, proc.stderr
        assert ("strict.yaml:7: sensors.s.gate: component 'strict' (gate, from fusion-decl 0.2) failed in "
                "initial_state(): RuntimeError: no state today") in proc.stderr, proc.stderr
        assert "Traceback" not in proc.stderr

