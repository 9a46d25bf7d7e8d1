"""A small seeded fuzz of hostile configs (issue 28 item 4): recording paths the system refuses or that
never end when read (a FIFO, a tty, /proc/self/mem, a symlink loop, 5,000 characters, a NUL), time offsets
against max_latency, a table of numbers given as a config, each mixed with the plain config mutations.
``fusion validate`` never exits 1 and never hangs: exit 0 (ok, perhaps with a note), or 2 with one line
naming the file."""
import signal
from pathlib import Path

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from fusion.cli import main
from fusion.fuzzing import CONFIG_OPS, HOSTILE_OPS, hostile_files, mutate_config, mutate_hostile

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = [(ROOT / "configs" / name).read_text().replace("../recordings/", f"{ROOT}/recordings/")
           for name in ("abps_ins.yaml", "uwb_pv_ukf.yaml", "example_2d.yaml")]
#: A bound on one validate call far above its ~1 s, so that a hang (a FIFO read) fails instead of
#: stopping the suite; not a timing assertion.
HANG_S = 120


class Hung(Exception):
    pass


def _alarm(signum, frame):
    raise Hung(f"fusion validate did not return within {HANG_S} s")


@pytest.fixture(scope="module")
def hostile_dir(tmp_path_factory):
    return hostile_files(tmp_path_factory.mktemp("hostile"))


edits = st.lists(st.tuples(st.sampled_from(CONFIG_OPS), st.integers(0, 1 << 16), st.integers(0, 1 << 16)),
                 max_size=1)
hostile = st.lists(st.tuples(st.sampled_from(HOSTILE_OPS), st.integers(0, 1 << 16), st.integers(0, 1 << 16)),
                   min_size=1, max_size=2)


@settings(max_examples=80, deadline=None, derandomize=True, database=None, phases=[Phase.explicit, Phase.generate],
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(base=st.sampled_from(range(len(CONFIGS))), bad=hostile, changes=edits)
def test_validate_ends_with_0_or_one_exit_2_line_on_a_hostile_config(tmp_path_factory, capsys, hostile_dir, base,
                                                                       bad, changes):
    text = CONFIGS[base]
    for op, i, j in bad:
        text = mutate_hostile(text, op, i, j, hostile_dir)
    for op, i, j in changes:
        text = mutate_config(text, op, i, j)
    cfg = tmp_path_factory.mktemp("cfg") / "c.yaml"
    cfg.write_text(text)
    capsys.readouterr()
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(HANG_S)
    try:
        code = main(["validate", str(cfg)])
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    out, err = capsys.readouterr()
    assert code in (0, 2), f"exit {code}: {err[-400:]}\n--- hostile: {bad} then {changes}"
    if code == 2:
        assert err.startswith(str(cfg)) and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    else:
        assert out.startswith(f"{cfg}: ok")


@pytest.mark.parametrize("j", range(16))
def test_every_hostile_recording_path_is_checked(tmp_path, capsys, hostile_dir, j):
    """Each path of HOSTILE_PATHS once on the smallest config: ok with a note for a stream (never read), one
    exit-2 line otherwise."""
    cfg = tmp_path / "c.yaml"
    cfg.write_text(mutate_hostile(CONFIGS[2], "recording", 0, j, hostile_dir))
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(HANG_S)
    try:
        code = main(["validate", str(cfg)])
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    out, err = capsys.readouterr()
    if code == 0:
        assert ": note: recording" in err and "not read" in err, err
    else:
        assert code == 2 and err.startswith(str(cfg)) and len(err.strip().splitlines()) == 1, err
