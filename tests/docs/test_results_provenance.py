"""Every results page (docs/results/*.md) records the commit and the hashes of the inputs it was made from
(experiments/provenance.py), and this check reports a page whose inputs changed since: a check of
hashes, not a rerun (issue 28 item 3). A page marked stale (its figures kept, the mark shown in the page)
passes with a warning, until its inputs change again."""
import importlib.util
import re
import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results"
PAGES = sorted(p for p in RESULTS.glob("*.md") if p.name != "README.md")   # README.md: the index


def _provenance():
    spec = importlib.util.spec_from_file_location("provenance", ROOT / "experiments" / "provenance.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


prov = _provenance()


def test_there_are_pages():
    assert len(PAGES) >= 9


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_a_page_records_its_commit_and_inputs_and_they_have_not_changed(page):
    info = prov.parse(page.read_text())
    assert info is not None, f"{page.name}: no provenance block; write it with experiments/provenance.py write_page"
    assert info["commit"] and info["inputs"], f"{page.name}: a provenance block without commit or inputs"
    moved = prov.changed(page)
    what = "; ".join(f"{p}: {a} when made, {b} now" for p, (a, b) in moved.items())
    if info["stale"] is None:
        assert not moved, (f"{page.name} is stale: its inputs changed since it was made ({what}). Regenerate it with "
                           f"the command at its top, or mark it: python experiments/provenance.py --mark-stale "
                           f"docs/results/{page.name} REASON")
        return
    now = {p: prov.input_hash(p) for p in info["inputs"]}
    again = {p for p, h in info["stale_against"].items() if now[p] != h}
    assert not again, f"{page.name}: marked stale, and its inputs changed again since the mark: {sorted(again)}"
    warnings.warn(f"{page.name} is marked stale: {info['stale']}", UserWarning)


@pytest.mark.parametrize("script", ["abps_fix_age", "abps_results", "fuzz_recordings", "imu_dropout",
                                    "imu_gps_mag_results", "real_logs", "smoother_seeds", "ultrasonic_3d",
                                    "uwb_sweep_page", "real_flights", "anywhere_results", "health_false_alarm"])
def test_each_script_writes_its_page_through_the_provenance_helper(script):
    text = (ROOT / "experiments" / f"{script}.py").read_text()
    assert "provenance.write_page(" in text and re.search(r"^INPUTS(_\w+)? = |^    inputs: list", text, re.M)
    assert not re.search(r"(OUT|PAGE|out)\.write_text\(", text), "a page written without its provenance block"


# ------------------------------------------------------------------ the check itself, on a page of its own
@pytest.fixture
def checkout(tmp_path):
    (tmp_path / "configs").mkdir()
    (tmp_path / "recordings").mkdir()
    (tmp_path / "configs" / "c.yaml").write_text("name: c  # a comment\nprocess: {type: pv, dims: 2}\n")
    (tmp_path / "recordings" / "r.log").write_text("0.0,uwb,B1,1.0\n")
    page = tmp_path / "page.md"
    prov.write_page(page, "# A page\n\nRegenerate: `python make.py`.\n\n| x | 1 |\n",
                    ["configs/c.yaml", "recordings/r.log"], root=tmp_path)
    return tmp_path, page


def test_a_value_changed_in_a_config_or_a_recording_makes_the_page_stale(checkout):
    root, page = checkout
    assert prov.parse(page.read_text())["inputs"].keys() == {"configs/c.yaml", "recordings/r.log"}
    assert prov.changed(page, root) == {}
    cfg = root / "configs" / "c.yaml"
    cfg.write_text("# reworded\nname: c\nprocess: {type: pv,   dims: 2}   # comments and layout do not count\n")
    assert prov.changed(page, root) == {}
    cfg.write_text("name: c\nprocess: {type: pv, dims: 3}\n")
    assert set(prov.changed(page, root)) == {"configs/c.yaml"}
    (root / "recordings" / "r.log").write_text("0.0,uwb,B1,1.5\n")
    assert set(prov.changed(page, root)) == {"configs/c.yaml", "recordings/r.log"}


def test_a_page_rewritten_keeps_one_block_and_its_text(checkout):
    root, page = checkout
    prov.write_page(page, page.read_text().replace("| x | 1 |", "| x | 2 |"), ["configs/c.yaml"], root=root)
    text = page.read_text()
    assert text.count(prov.BEGIN) == 1 and "| x | 2 |" in text
    assert prov.parse(text)["inputs"].keys() == {"configs/c.yaml"}


def test_a_stale_mark_is_shown_and_holds_until_the_inputs_change_again(checkout):
    root, page = checkout
    (root / "configs" / "c.yaml").write_text("name: c\nprocess: {type: pv, dims: 3}\n")
    prov.mark_stale(page, "dims changed; regenerating takes an hour", root=root)
    text = page.read_text()
    assert text.startswith("# A page\n\n" + prov.BANNER + "\n> **Stale**: dims changed")
    info = prov.parse(text)
    assert info["stale"].startswith("dims changed")
    assert info["stale_against"]["configs/c.yaml"] == prov.input_hash("configs/c.yaml", root)
    assert info["inputs"]["configs/c.yaml"] != info["stale_against"]["configs/c.yaml"]   # the made-with hash kept
    prov.mark_stale(page, "marked again", root=root)
    again = page.read_text()
    assert again.count(prov.BANNER) == 1 and "\n> **Stale**: marked again (Provenance" in again
    assert "(Provenance, at the end of the page.)\n\nRegenerate: " in again
    prov.write_page(page, "# A page\n\nregenerated\n", ["configs/c.yaml"], root=root)   # a rerun clears the mark
    assert prov.parse(page.read_text())["stale"] is None and prov.BANNER not in page.read_text()
