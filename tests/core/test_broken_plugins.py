"""A broken installed plugin stops only what uses it (fusion/registry.py, docs/writing-plugins.md "When a
plugin is broken"): its module fails to import, it registers a built-in's name, or ``add_lazy`` points at a
missing module or at a class of the wrong kind or name. ``fusion plugins`` lists the rest and the broken one
(exit 2, one line each on stderr); a run or validation that does not use it works, with one warning line
naming the package and FUSION_BLOCK_PLUGINS; one that uses it is exit 2 with that line; never a traceback."""
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PLUGIN = '''\
import os
from fusion import hookimpl
from fusion.api import MeasurementModel

MODE = os.environ.get("BROKEN_MODE", "")
if MODE == "import":
    import fusion_no_such_dependency_xyz


class Height(MeasurementModel):
    """Height [m] from p_z."""
    name = "height"
    dim = 1

    def h(self, x):
        return -x[..., 1:2]


class Other(Height):
    """Another [m]."""
    name = "other"


@hookimpl
def fusion_register_components(registry):
    registry.add(Height)
    if MODE == "clash":
        class Range(Height):
            """A second range."""
            name = "range"
        registry.add(Range)
    if MODE == "lazy_missing":
        registry.add_lazy("measurement", "lazy", "fusion_broken.nosuch:Thing")
    if MODE == "lazy_kind":
        registry.add_lazy("sink", "lazy", "fusion_broken.plugin:Height")
    if MODE == "lazy_name":
        registry.add_lazy("measurement", "lazy", "fusion_broken.plugin:Height")
    if MODE == "raises":
        raise RuntimeError("registration boom")
    if MODE == "hijack":
        from fusion.api import Sink, Source

        class Hijack(Source):
            """Claims the built-ins' schemes."""
            name = "hijack"
            schemes = ("file", "socket")

            def lines(self):
                return iter(())

        class CsvToo(Sink):
            """Claims .csv."""
            name = "csv_too"
            suffixes = (".csv",)

        registry.add(Hijack)
        registry.add(CsvToo)
    registry.add(Other)
'''
CONFIG = """\
name: c
process: {{type: pv, dims: 2, spectral_density: 0.1}}
initial: {{mean: {{p: [0, 0], v: [0, 0]}}, sd: {{p: 1.0, v: 1.0}}}}
filter: ekf
beacons: {{B1: [0.0, 0.0]}}
sensors:
  s: {{model: {model}, noise: {{sd: 0.5}}}}
"""


@pytest.fixture
def broken(tmp_path):
    """Run ``fusion ARGS`` with the package fusion-broken 0.3 installed (its BROKEN_MODE picks the fault)."""
    site = tmp_path / "site"
    (site / "fusion_broken").mkdir(parents=True)
    (site / "fusion_broken" / "__init__.py").write_text("")
    (site / "fusion_broken" / "plugin.py").write_text(PLUGIN)
    info = site / "fusion_broken-0.3.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: fusion-broken\nVersion: 0.3\n")
    (info / "entry_points.txt").write_text("[fusion]\nbrk = fusion_broken.plugin\n")
    for model in ("range", "height", "position", "lazy", "other", "nosuch"):
        (tmp_path / f"{model}.yaml").write_text(CONFIG.format(model=model))
    env = {k: v for k, v in os.environ.items() if k != "FUSION_DISABLE_PLUGIN_AUTOLOAD"}
    env["PYTHONPATH"] = os.pathsep.join([str(site), env.get("PYTHONPATH", "")])
    env["COLUMNS"] = "400"

    def fusion(mode, *args, **extra):
        cmd = [sys.executable, "-c", "import sys; from fusion.cli import main; sys.exit(main())", *args]
        proc = subprocess.run(cmd, env={**env, "BROKEN_MODE": mode, **extra}, cwd=tmp_path, capture_output=True,
                              text=True)
        assert "Traceback" not in proc.stderr and "internal error" not in proc.stderr, proc.stderr
        return proc

    fusion.site = site
    return fusion


WAY_OUT = "in plugin 'brk' of the installed package 'fusion-broken 0.3'; fix or uninstall it, or run with FUSION_BLOCK_PLUGINS=brk"


def test_a_plugin_whose_module_fails_to_import(broken):
    where = f"{broken.site / 'fusion_broken' / 'plugin.py'}:7: "
    listed = broken("import", "plugins")
    assert listed.returncode == 2
    assert "range" in listed.stdout and "BROKEN" in listed.stdout and "fusion-broken 0.3" in listed.stdout
    assert listed.stderr.splitlines() == [
        f"fusion plugins: error: {where}its module 'fusion_broken.plugin' cannot be imported: ModuleNotFoundError: "
        f"No module named 'fusion_no_such_dependency_xyz': {WAY_OUT} (FUSION_DISABLE_PLUGIN_AUTOLOAD=1 skips every "
        "third-party plugin)"]
    # a config that does not use it: validated and run, one warning line
    ok = broken("import", "validate", "range.yaml")
    assert ok.returncode == 0 and ok.stdout.startswith("range.yaml: ok")
    (warning,) = ok.stderr.splitlines()
    assert warning.startswith("fusion validate: warning: plugin 'brk' of the installed package 'fusion-broken 0.3' "
                              f"is broken ({where}its module") and "FUSION_BLOCK_PLUGINS=brk" in warning
    run = broken("import", "run", str(ROOT / "configs" / "example_2d.yaml"), "-q", "-o", "out.csv")
    assert run.returncode == 0 and len(run.stderr.splitlines()) == 1 and "fusion run: warning: " in run.stderr
    # a config that uses one of its components: exit 2, naming it as the likely cause
    bad = broken("import", "validate", "height.yaml")
    assert bad.returncode == 2 and len(bad.stderr.splitlines()) == 2
    assert "height.yaml:7: sensors.s.model: unknown measurement 'height'" in bad.stderr
    assert "plugin 'brk' of the installed package 'fusion-broken 0.3' could not be loaded and may provide it" in bad.stderr
    # blocked: nothing to say
    quiet = broken("import", "plugins", FUSION_BLOCK_PLUGINS="brk")
    assert quiet.returncode == 0 and quiet.stderr == "" and "BROKEN" not in quiet.stdout


def test_a_plugin_registering_a_builtin_name(broken):
    listed = broken("clash", "plugins", "--kind", "measurement")
    assert listed.returncode == 2 and "height" in listed.stdout and "other" in listed.stdout
    (line,) = listed.stderr.splitlines()
    assert (f"{broken.site / 'fusion_broken' / 'plugin.py'}:31: measurement 'range' registered twice: by "
            "fusion-estimator") in line and WAY_OUT in line
    # the rest of the plugin works, with a warning
    ok = broken("clash", "validate", "height.yaml")
    assert ok.returncode == 0 and "a config using measurement 'range' is refused" in ok.stderr
    assert len(ok.stderr.splitlines()) == 1
    # 'range' is ambiguous: exit 2 until one of the two is blocked
    bad = broken("clash", "validate", "range.yaml")
    assert bad.returncode == 2 and "range.yaml:7: sensors.s.model: " in bad.stderr and WAY_OUT in bad.stderr
    assert broken("clash", "validate", "range.yaml", FUSION_BLOCK_PLUGINS="brk").returncode == 0


@pytest.mark.parametrize("mode, what", [
    ("lazy_missing", "measurement 'lazy' = 'fusion_broken.nosuch:Thing' cannot be loaded: ModuleNotFoundError: "
                     "No module named 'fusion_broken.nosuch'"),
    ("lazy_kind", "sink 'lazy' = 'fusion_broken.plugin:Height' cannot be loaded: registered lazily as sink 'lazy' "
                  "but declares measurement 'height'"),
    ("lazy_name", "measurement 'lazy' = 'fusion_broken.plugin:Height' cannot be loaded: registered lazily as "
                  "measurement 'lazy' but declares measurement 'height'"),
])
def test_a_lazy_registration_with_a_bad_target(broken, mode, what):
    line = {"lazy_missing": 33, "lazy_kind": 35, "lazy_name": 37}[mode]
    what = f"{broken.site / 'fusion_broken' / 'plugin.py'}:{line}: {what}"     # where add_lazy was called
    listed = broken(mode, "plugins")
    assert listed.returncode == 2 and "height" in listed.stdout and "BROKEN" in listed.stdout
    assert listed.stderr.splitlines() == [f"fusion plugins: error: {what}: {WAY_OUT} (FUSION_DISABLE_PLUGIN_AUTOLOAD=1 "
                                          "skips every third-party plugin)"]
    verbose = broken(mode, "plugins", "--verbose")
    assert verbose.returncode == 2 and "Height [m] from p_z." in verbose.stdout and "broken" in verbose.stdout
    ok = broken(mode, "validate", "height.yaml")       # lazy components are imported only when used
    assert ok.returncode == 0 and ok.stderr == ""
    if mode != "lazy_kind":
        bad = broken(mode, "validate", "lazy.yaml")
        assert bad.returncode == 2 and f"lazy.yaml:7: sensors.s.model: {what}: {WAY_OUT}" in bad.stderr


def test_a_registration_hook_that_raises(broken):
    ok = broken("raises", "validate", "height.yaml")      # registered before the exception: kept
    assert ok.returncode == 0 and len(ok.stderr.splitlines()) == 1
    assert "fusion_register_components raised RuntimeError: registration boom" in ok.stderr
    bad = broken("raises", "validate", "other.yaml")
    assert bad.returncode == 2 and "unknown measurement 'other'" in bad.stderr and "registration boom" in bad.stderr


def test_a_plugin_claiming_a_builtin_scheme_or_suffix(broken, tmp_path):
    """A source claiming file:// and socket://, a sink claiming .csv (such a source would silently
    take over file:// inputs, the run read nothing and exit 0): refused like a name registered twice, the
    built-ins keep theirs, and fusion plugins says so."""
    listed = broken("hijack", "plugins")
    assert listed.returncode == 2
    lines = listed.stderr.splitlines()
    assert any("source 'hijack'" in ln and "claims file://, already read by source 'recording'" in ln for ln in lines)
    assert any("sink 'csv_too'" in ln and "claims .csv, already written by sink 'estimates'" in ln for ln in lines)
    log = ROOT / "recordings" / "example_2d.log"
    cfg = ROOT / "configs" / "example_2d.yaml"
    out = tmp_path / "e.csv"
    run = broken("hijack", "run", str(cfg), "--input", f"file://{log}", "-q", "-o", str(out))
    assert run.returncode == 0 and out.read_text().count("\n") > 100      # read and written by the built-ins
    closed = broken("hijack", "run", str(cfg), "--input", "socket://127.0.0.1:1", "-q")
    assert closed.returncode == 2
