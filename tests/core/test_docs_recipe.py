"""docs/writing-plugins.md's measurement-model recipe runs as written: its blocks are written to files by
the path on their first line, the package is installed (a dist-info with its entry point, what `pip
install` leaves), the author's tests pass the kit, `fusion simulate` uses its simulator and `fusion run`
its model from YAML; and the project's own suite is unaffected by it (tests/conftest.py turns autoload
off; test_the_projects_tests_ignore_an_installed_plugin checks it)."""
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "writing-plugins.md"
SCENARIO = """\
name: baro_walk
seed: 3
dim: 3
trajectory:
  type: waypoints
  speed: 1.0
  max_accel: 0.5
  radius: 1.0
  waypoints:
    - [0.0, 0.0, 0.0]
    - [10.0, 0.0, -4.0]
    - [10.0, 10.0, -6.0]
sensors:
  baro: {type: baro, rate_hz: 10, noise_sd: 0.5, offset: 2.0}
"""


def recipe_files() -> dict[str, str]:
    """{path: text} of every fenced block whose first line is ``# PATH`` (the recipe's files)."""
    text = DOC.read_text()
    start = text.index("## Recipe: a measurement model")
    out = {}
    for block in re.findall(r"```[a-z]*\n(.*?)```", text[start:], re.S):
        first, _, body = block.partition("\n")
        m = re.fullmatch(r"# ([\w./-]+\.(?:py|toml|yaml))", first.strip())
        if m:
            out[m.group(1)] = body if m.group(1).endswith((".toml", ".yaml")) else block
    return out


def install(tmp_path: Path) -> tuple[Path, dict[str, str]]:
    files = recipe_files()
    assert {"fusion_baro/plugin.py", "pyproject.toml", "tests/test_baro.py", "baro.yaml"} <= set(files)
    pkg = tmp_path / "fusion-baro"
    for rel, text in files.items():
        (pkg / rel).parent.mkdir(parents=True, exist_ok=True)
        (pkg / rel).write_text(text)
    (pkg / "fusion_baro" / "__init__.py").write_text("")
    info = tmp_path / "site" / "fusion_baro-0.1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: fusion-baro\nVersion: 0.1.0\n")
    entry = re.search(r"\[project.entry-points.fusion\]\n(.*)", files["pyproject.toml"]).group(1)
    (info / "entry_points.txt").write_text("[fusion]\n" + entry.replace('"', "") + "\n")
    env = {k: v for k, v in os.environ.items() if k != "FUSION_DISABLE_PLUGIN_AUTOLOAD"}
    env["COLUMNS"] = "250"   # the plugin table on one line a row
    env["PYTHONPATH"] = os.pathsep.join([str(tmp_path / "site"), str(pkg), env.get("PYTHONPATH", "")])
    return pkg, env


def fusion(env, *args, cwd):
    return subprocess.run([sys.executable, "-c", "import sys; from fusion.cli import main; sys.exit(main())", *args],
                          env=env, cwd=cwd, capture_output=True, text=True)


def test_the_recipe_passes_the_kit_and_runs_from_yaml(tmp_path):
    pkg, env = install(tmp_path)
    tests = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/test_baro.py"],
                           env=env, cwd=pkg, capture_output=True, text=True)
    assert tests.returncode == 0, tests.stdout + tests.stderr
    assert "3 passed" in tests.stdout
    listed = fusion(env, "plugins", cwd=pkg)
    assert listed.returncode == 0 and re.search(r"measurement\W+baro\W+fusion-baro 0\.1\.0", listed.stdout), listed.stdout
    (pkg / "walk.yaml").write_text(SCENARIO)
    sim = fusion(env, "simulate", "walk.yaml", "-o", "baro.log", cwd=pkg)
    assert sim.returncode == 0, sim.stderr
    run = fusion(env, "run", "baro.yaml", "--input", "baro.log", "-o", "out.csv", "--summary-json", "s.json", cwd=pkg)
    assert run.returncode == 0, run.stderr
    import json

    summary = json.loads((pkg / "s.json").read_text())
    assert summary["sensors"]["baro"]["used"] == summary["sensors"]["baro"]["received"] > 100
    est = np.genfromtxt(pkg / "out.csv", delimiter=",", names=True, dtype=None, encoding=None)
    # the walk climbs 6 m (p_z from 0 to -6, NED): the filter follows the height, not x or y
    assert abs(est["pz"][-1] - (-6.0)) < 1.0 and est["sd_pz"][-1] < 0.5
    # without noise: refused at the sensor's line, exit 2
    (pkg / "nonoise.yaml").write_text((pkg / "baro.yaml").read_text().replace(", noise: {sd: 0.5}", ""))
    bad = fusion(env, "validate", "nonoise.yaml", cwd=pkg)
    assert bad.returncode == 2 and "nonoise.yaml:6" in bad.stderr and "needs 'noise:'" in bad.stderr, bad.stderr


def test_the_projects_tests_ignore_an_installed_plugin(tmp_path):
    """With the recipe's package on the path and its entry point installed, the project's tests that look at
    the registry (the registry test expects the built-ins only; the contract tests parametrise over every
    registered filter and gate) still pass: tests/conftest.py disables third-party autoload."""
    _, env = install(tmp_path)
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                          str(ROOT / "tests" / "core" / "test_registry.py"),
                          str(ROOT / "tests" / "filters" / "test_filters_contracts.py"),
                          str(ROOT / "tests" / "test_gates.py")],
                         env=env, cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr       # 5 would be: no tests ran
    probe = "from fusion.registry import make_plugin_manager as m; print('baro' in m()[1].names('measurement'))"
    seen = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True)
    assert seen.stdout.strip() == "True", seen.stderr        # it is installed, and loads outside the suite
