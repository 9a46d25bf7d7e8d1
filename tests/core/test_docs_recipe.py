"""docs/writing-plugins.md's measurement-model recipe runs as written: its blocks are written
to files by the path on their first line, its shell steps are run in order — `pip install ./fusion-baro`
(really through pip when the build backend can build offline, else the dist-info pip leaves), the author's
tests (the kit), `fusion plugins`, `fusion simulate walk.yaml` with its simulator and `fusion run` with its
model from YAML; and the project's own suite is unaffected by it (tests/conftest.py turns autoload off;
test_the_projects_tests_ignore_an_installed_plugin checks it)."""
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "writing-plugins.md"


def recipe() -> tuple[dict[str, str], list[str]]:
    """({path: text} of every fenced block whose first line is ``# PATH``, the recipe's shell steps): the
    page's "Recipe" section only."""
    text = DOC.read_text()
    start = text.index("## Recipe: a measurement model")
    text = text[start:text.index("\n## ", start + 1)]
    files, steps = {}, []
    for lang, block in re.findall(r"```([a-z]*)\n(.*?)```", text, re.S):
        if lang == "sh":
            steps += [line.strip() for line in block.splitlines() if line.strip()]
            continue
        first, _, body = block.partition("\n")
        m = re.fullmatch(r"# ([\w./-]+\.(?:py|toml|yaml))", first.strip())
        if m:
            files[m.group(1)] = body if m.group(1).endswith((".toml", ".yaml")) else block
    return files, steps


def can_build_offline() -> bool:
    """Whether ``pip install --no-build-isolation`` can build the recipe's package here without the network:
    setuptools >= 70.1 builds a wheel by itself, an older one needs the ``wheel`` package."""
    try:
        import setuptools
    except ImportError:
        return False
    major, minor = (int(v) for v in re.findall(r"\d+", setuptools.__version__)[:2])
    if (major, minor) >= (70, 1):
        return True
    try:
        import wheel  # noqa: F401
    except ImportError:
        return False
    return True


def write_recipe(tmp_path: Path) -> tuple[Path, list[str], dict[str, str]]:
    files, steps = recipe()
    assert {"fusion-baro/fusion_baro/plugin.py", "fusion-baro/pyproject.toml", "fusion-baro/tests/test_baro.py",
            "baro.yaml", "walk.yaml"} <= set(files)
    work = tmp_path / "work"
    for rel, text in files.items():
        (work / rel).parent.mkdir(parents=True, exist_ok=True)
        (work / rel).write_text(text)
    (work / "fusion-baro" / "fusion_baro" / "__init__.py").write_text("")   # "(empty)"
    env = {k: v for k, v in os.environ.items() if k != "FUSION_DISABLE_PLUGIN_AUTOLOAD"}
    env["COLUMNS"] = "250"   # the plugin table on one line a row
    env["PYTHONPATH"] = os.pathsep.join([str(tmp_path / "site"), env.get("PYTHONPATH", "")])
    return work, steps, env


def pip_install(tmp_path: Path, package: Path, env: dict[str, str], real: bool = True) -> subprocess.CompletedProcess:
    """``pip install PACKAGE`` into a folder of its own (on the children's PYTHONPATH): really through pip
    and the package's build backend when it can build offline (no dependencies: fusion is the one under
    test), else (or not ``real``: ~7 s of pip saved) the dist-info pip leaves (its METADATA and
    entry_points.txt) beside the package's source."""
    site = tmp_path / "site"
    if real and can_build_offline():
        return subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                               "--no-index", "--target", str(site), str(package)],
                              env=env, capture_output=True, text=True)
    import tomllib

    meta = tomllib.loads((package / "pyproject.toml").read_text())["project"]
    info = site / f"{meta['name'].replace('-', '_')}-{meta['version']}.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {meta['name']}\nVersion: {meta['version']}\n")
    eps = "".join(f"{k} = {v}\n" for k, v in meta["entry-points"]["fusion"].items())
    (info / "entry_points.txt").write_text("[fusion]\n" + eps)
    (site / "fusion_baro").symlink_to(package / "fusion_baro")
    return subprocess.CompletedProcess([], 0, "", "")


def install(tmp_path: Path) -> tuple[Path, dict[str, str]]:
    """The recipe's files written and its package installed: (the package's folder, the environment)."""
    work, _, env = write_recipe(tmp_path)
    done = pip_install(tmp_path, work / "fusion-baro", env, real=False)
    assert done.returncode == 0, done.stdout + done.stderr
    return work / "fusion-baro", env


def fusion(env, *args, cwd):
    return subprocess.run([sys.executable, "-c", "import sys; from fusion.cli import main; sys.exit(main())", *args],
                          env=env, cwd=cwd, capture_output=True, text=True)


def run_steps(tmp_path: Path, work: Path, steps: list[str], env: dict[str, str]) -> dict[str, subprocess.CompletedProcess]:
    """The recipe's shell steps, each as written: ``pip install DIR``, ``cd DIR && pytest ARGS && cd ..``,
    ``fusion ARGS`` (the fusion under test); any other line fails the test (the page would say a step this
    test does not run). Returns each step's result by its text."""
    done = {}
    for step in steps:
        words = shlex.split(step)
        if words[:2] == ["pip", "install"] and len(words) == 3:
            out = pip_install(tmp_path, work / words[2], env)
        elif words[0] == "cd" and words[2:4] == ["&&", "pytest"] and words[-3:] == ["&&", "cd", ".."]:
            out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *words[4:-3]],
                                 env=env, cwd=work / words[1], capture_output=True, text=True)
        elif words[0] == "fusion":
            out = fusion(env, *words[1:], cwd=work)
        else:
            raise AssertionError(f"docs/writing-plugins.md recipe: a step this test does not know how to run: {step!r}")
        assert out.returncode == 0, f"{step}: exit {out.returncode}\n{out.stdout}{out.stderr}"
        done[step] = out
    return done


def test_the_recipe_runs_as_written(tmp_path):
    """Every file of the recipe by its path, then its shell steps in order: pip install, the author's tests
    (the kit), fusion plugins, fusion simulate (its simulator), fusion run (its model, from YAML)."""
    work, steps, env = write_recipe(tmp_path)
    assert [s.split()[0] for s in steps] == ["pip", "cd", "fusion", "fusion", "fusion"], steps
    done = run_steps(tmp_path, work, steps, env)
    tests = next(out for step, out in done.items() if "pytest" in step)
    assert "3 passed" in tests.stdout, tests.stdout
    listed = done["fusion plugins"]
    assert re.search(r"measurement\W+baro\W+fusion-baro 0\.1\.0", listed.stdout), listed.stdout
    assert (work / "baro.log").is_file()
    run = fusion(env, "run", "baro.yaml", "--input", "baro.log", "-o", "out.csv", "--summary-json", "s.json", cwd=work)
    assert run.returncode == 0, run.stderr
    import json

    summary = json.loads((work / "s.json").read_text())
    assert summary["sensors"]["baro"]["used"] == summary["sensors"]["baro"]["received"] > 100
    est = np.genfromtxt(work / "out.csv", delimiter=",", names=True, dtype=None, encoding=None)
    # the walk climbs 6 m (p_z from 0 to -6, NED): the filter follows the height, not x or y
    assert abs(est["pz"][-1] - (-6.0)) < 1.0 and est["sd_pz"][-1] < 0.5
    # without noise: refused at the sensor's line, exit 2
    (work / "nonoise.yaml").write_text((work / "baro.yaml").read_text().replace(", noise: {sd: 0.5}", ""))
    bad = fusion(env, "validate", "nonoise.yaml", cwd=work)
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
