"""Fixtures shared by the test folders.

The suite is hermetic: third-party plugins installed in the environment are not loaded
(``FUSION_DISABLE_PLUGIN_AUTOLOAD=1`` for this process and the commands it starts), so the project's
tests neither run nor depend on someone else's components. The tests of entry-point loading turn
autoload back on for themselves (the ``installed_example`` fixture)."""
import os
import sys
from pathlib import Path

import pytest

os.environ["FUSION_DISABLE_PLUGIN_AUTOLOAD"] = "1"

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "fusion-altimeter"


@pytest.fixture
def installed_example(tmp_path, monkeypatch):
    """Make the example package importable with installed metadata (a dist-info with its entry point),
    exactly what `pip install examples/fusion-altimeter` leaves in site-packages."""
    site = tmp_path / "site"
    (site / "fusion_altimeter-0.1.0.dist-info").mkdir(parents=True)
    (site / "fusion_altimeter-0.1.0.dist-info" / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: fusion-altimeter\nVersion: 0.1.0\n")
    (site / "fusion_altimeter-0.1.0.dist-info" / "entry_points.txt").write_text(
        "[fusion]\naltimeter = fusion_altimeter.plugin\n")
    monkeypatch.delenv("FUSION_DISABLE_PLUGIN_AUTOLOAD", raising=False)  # this test loads entry points
    monkeypatch.syspath_prepend(str(EXAMPLE))
    monkeypatch.syspath_prepend(str(site))
    import fusion.registry

    monkeypatch.setattr(fusion.registry, "_DEFAULT", None)  # the CLI builds its registry afresh
    yield
    for name in [m for m in sys.modules if m.split(".")[0] == "fusion_altimeter"]:
        sys.modules.pop(name, None)
