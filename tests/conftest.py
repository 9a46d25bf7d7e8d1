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

#: The slowest tests (`pytest --durations=0`), marked `slow` so that `pytest -m "not slow"` is a quick loop
#: while developing; the default `pytest` (what CI runs) runs them all. Listed here, by test function, so a
#: test keeps its file's layout; a new test slower than ~3 s belongs here or gets `@pytest.mark.slow`.
SLOW_TESTS = {
    "tests/tui/test_tui_live_view.py::test_every_shipped_config_replays_in_the_view_to_the_end",
    "tests/smoothing/test_every_config.py::test_smoothed_run_of_the_shipped_config",
    "tests/tui/test_tui_smooth_lag.py::test_the_second_trace_is_the_fixed_lag_smoother_of_fusion_run",
    "tests/systems/test_uwb.py::test_ukf_within_a_few_percent_of_ekf_in_every_case",
    "tests/core/test_pipeline.py::test_memory_does_not_grow_with_the_length_of_a_run",
    "tests/smoothing/test_ins_consistency.py::test_smoothed_ins_is_consistent",
    "tests/tui/test_tui_smooth_lag.py::test_picture_with_the_smoothed_trace",
    "tests/tui/test_tui_snapshots.py::test_main_screen",
    "tests/core/test_broken_plugins.py::test_a_lazy_registration_with_a_bad_target",
    "tests/smoothing/test_fixed_lag_live.py::test_push_loop_gives_the_numbers_of_the_batch_loop",
    "tests/tui/test_tui_smooth_lag.py::test_while_running_the_smoothed_trace_is_lag_seconds_behind",
    "tests/sweep/test_engines.py::test_pool_and_dask_rows_equal_serial_rows",
    "tests/systems/test_imu_gps_mag.py::test_an_imu_dropout_while_gps_and_magnetometer_go_on",
    "tests/smoothing/test_quaternion_smoothing.py::test_smoothed_attitude_nees_is_inside_its_bounds",
    "tests/core/test_docs_recipe.py::test_the_recipe_runs_as_written",
    "tests/tui/test_tui_smooth_lag.py::test_without_the_option_there_is_no_second_trace",
}


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: a test of several seconds; `pytest -m 'not slow'` skips it")


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.nodeid.split("[")[0] in SLOW_TESTS:
            item.add_marker(pytest.mark.slow)

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
