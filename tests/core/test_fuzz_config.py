"""Fuzz ``fusion validate`` with mutated shipped configs (issue 10 item 9): it never raises and never
exits 1, whatever the YAML holds (exit 0, or 2 with one line naming the file)."""
from pathlib import Path

from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from fusion.cli import main
from fusion.fuzzing import CONFIG_OPS, mutate_config

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = [(ROOT / "configs" / name).read_text().replace("../recordings/", f"{ROOT}/recordings/")
           for name in ("abps_ins.yaml", "uwb_pv_ukf.yaml", "example_2d.yaml")]
edits = st.lists(st.tuples(st.sampled_from(CONFIG_OPS), st.integers(0, 1 << 16), st.integers(0, 1 << 16)),
                 min_size=1, max_size=3)


@settings(max_examples=150, deadline=None, derandomize=True, database=None, phases=[Phase.explicit, Phase.generate],
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(base=st.sampled_from(range(len(CONFIGS))), changes=edits)
def test_validate_never_raises_on_a_mutated_config(tmp_path_factory, capsys, base, changes):
    text = CONFIGS[base]
    for op, i, j in changes:
        text = mutate_config(text, op, i, j)
    cfg = tmp_path_factory.mktemp("cfg") / "c.yaml"
    cfg.write_text(text)
    capsys.readouterr()
    code = main(["validate", str(cfg)])
    out, err = capsys.readouterr()
    assert code in (0, 2), f"exit {code}: {err[-400:]}\n--- config:\n{text}"
    if code == 2:
        assert err.startswith(str(cfg)) and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    else:
        assert out.startswith(f"{cfg}: ok")
