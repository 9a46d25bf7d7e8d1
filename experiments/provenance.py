"""The provenance block of a results page (docs/results/*.md): the commit it was made at and a hash of each
input it was made from (the configs, scenarios and recordings its script reads), so that a page whose
inputs changed since says so, by a check of hashes rather than a rerun (tests/docs/test_results_provenance.py
in the suite; ``python experiments/provenance.py --check`` by hand).

A script writes its page through :func:`write_page` with its inputs::

    from provenance import write_page          # experiments/ is on the script's path
    write_page(OUT, text, ["configs/abps_ins.yaml", "recordings/abps_mine.log", "scenarios/abps_mine.yaml"])

Hashes: sha256 (the first 16 hex digits) of a recording's bytes; of a YAML file's parsed content, so that a
comment or a layout change does not make a page stale while any value that can change a figure does.
A page whose inputs changed and that cannot be regenerated at once is marked stale
(``--mark-stale PAGE REASON``): the mark is shown in the page and names the inputs' hashes it was made
against, so the check passes (with a warning) until the inputs change again.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Iterable, Sequence

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
BEGIN, END = "<!-- provenance: experiments/provenance.py -->", "<!-- /provenance -->"
BANNER = "<!-- stale: experiments/provenance.py -->"
_ROW = re.compile(r"^\| `([^`]+)` \| `([0-9a-f]{16}|missing)` \|(?: `([0-9a-f]{16}|missing)` \|)?$")
_COMMIT = re.compile(r"^Made at commit `([^`]+)`(?: \((uncommitted changes)\))?")
_STALE = re.compile(r"^\*\*Stale\*\*: (.*)$")


def content_hash(data: bytes, suffix: str) -> str:
    """sha256 (16 hex digits) of a file's bytes; for ``.yaml``/``.yml``, of its parsed content (canonical
    JSON), so that comments and layout do not count. YAML that does not parse is hashed as bytes."""
    if suffix in (".yaml", ".yml"):
        import yaml

        try:
            data = json.dumps(yaml.safe_load(data), sort_keys=True, default=str).encode()
        except yaml.YAMLError:
            pass
    return hashlib.sha256(data).hexdigest()[:16]


def input_hash(path: str, root: Path = ROOT) -> str:
    """The hash of ``path`` (relative to the checkout) as it is now; ``missing`` when it is gone."""
    p = root / path
    return content_hash(p.read_bytes(), p.suffix) if p.is_file() else "missing"


def input_hash_at(commit: str, path: str, root: Path = ROOT) -> str:
    """The hash of ``path`` as it was at ``commit`` (git), ``missing`` when it was not there."""
    done = subprocess.run(["git", "show", f"{commit}:{path}"], cwd=root, capture_output=True)
    return content_hash(done.stdout, Path(path).suffix) if done.returncode == 0 else "missing"


def head_commit(root: Path = ROOT) -> str:
    """The checkout's commit, with `` + uncommitted changes`` when tracked files other than the results
    pages (written one after another by a regeneration) differ from it."""
    sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", ".", ":!docs/results"],
                           cwd=root, capture_output=True, text=True).stdout.strip()
    return (sha or "unknown") + (" + uncommitted changes" if dirty else "")


def block(commit: str, hashes: dict[str, str], stale: str | None = None,
          stale_against: dict[str, str] | None = None) -> str:
    """The block's markdown: the commit, one row an input with its hash (and with a stale mark, the hash
    each input had when the mark was made)."""
    sha, _, note = commit.partition(" + ")
    lines = [BEGIN, "## Provenance", "",
             f"Made at commit `{sha}`{' (' + note + ')' if note else ''} from these inputs (sha256, 16 hex "
             "digits; a YAML file by its parsed content). `tests/docs/test_results_provenance.py` reports the page "
             "when one changes: regenerate it with the command at the top.", ""]
    if stale is not None:
        lines += [f"**Stale**: {stale}", ""]
    against = stale_against or {}
    lines += ["| input | sha256 |" + (" when marked stale |" if stale is not None else ""),
              "|---|---|" + ("---|" if stale is not None else "")]
    for path, h in hashes.items():
        lines.append(f"| `{path}` | `{h}` |" + (f" `{against.get(path, h)}` |" if stale is not None else ""))
    return "\n".join(lines + [END])


def parse(text: str) -> dict | None:
    """``{"commit", "inputs": {path: hash}, "stale": reason or None, "stale_against": {path: hash}}`` of the
    page's block, or None when it has none."""
    if BEGIN not in text or END not in text:
        return None
    body = text[text.index(BEGIN):text.index(END)]
    out: dict = {"commit": None, "inputs": {}, "stale": None, "stale_against": {}}
    for line in body.splitlines():
        if m := _COMMIT.match(line):
            out["commit"] = m.group(1) + (f" + {m.group(2)}" if m.group(2) else "")
        elif m := _STALE.match(line):
            out["stale"] = m.group(1)
        elif m := _ROW.match(line):
            out["inputs"][m.group(1)] = m.group(2)
            if m.group(3):
                out["stale_against"][m.group(1)] = m.group(3)
    return out


def with_block(text: str, new_block: str) -> str:
    """``text`` with its provenance block replaced by ``new_block`` (appended when it has none)."""
    if BEGIN in text and END in text:
        return text[:text.index(BEGIN)] + new_block + text[text.index(END) + len(END):]
    return text.rstrip("\n") + "\n\n" + new_block + "\n"


def write_page(path: str | Path, text: str, inputs: Iterable[str], root: Path = ROOT) -> None:
    """Write a results page with its provenance block (this checkout's commit, the inputs' hashes now)."""
    hashes = {p: input_hash(p, root) for p in sorted(set(inputs))}
    Path(path).write_text(with_block(text, block(head_commit(root), hashes)))


def changed(page: str | Path, root: Path = ROOT) -> dict[str, tuple[str, str]]:
    """The inputs of ``page`` whose hash is not the recorded one: {path: (recorded, now)}."""
    info = parse(Path(page).read_text())
    if info is None:
        return {}
    now = {p: input_hash(p, root) for p in info["inputs"]}
    return {p: (h, now[p]) for p, h in info["inputs"].items() if now[p] != h}


def mark_stale(page: str | Path, reason: str, root: Path = ROOT) -> None:
    """Mark ``page`` stale with ``reason``, against its inputs' hashes now."""
    page = Path(page)
    text = page.read_text()
    info = parse(text)
    if info is None:
        raise SystemExit(f"{page}: no provenance block to mark")
    now = {p: input_hash(p, root) for p in info["inputs"]}
    text = with_block(text, block(info["commit"], info["inputs"], reason, now))
    page.write_text(with_banner(text, f"> **Stale**: {reason} (Provenance, at the end of the page.)"))


def with_banner(text: str, banner: str) -> str:
    """``text`` with ``banner`` under its title (replacing an earlier one): a stale mark a reader sees first."""
    if BANNER in text:
        head, _, rest = text.partition(BANNER)
        text = head.rstrip("\n") + "\n\n" + rest.split("\n\n", 1)[1] if "\n\n" in rest else head
    title, sep, rest = text.partition("\n")
    return f"{title}\n\n{BANNER}\n{banner}\n{rest}" if sep else text


def backfill(page: str | Path, inputs: Sequence[str], commit: str | None = None, root: Path = ROOT) -> None:
    """Give a page made before provenance blocks its block: the commit its figures were made at (default:
    the last commit that changed the page), and its inputs' hashes at that commit (from git history)."""
    page = Path(page)
    rel = page.resolve().relative_to(root)
    commit = subprocess.run(["git", "log", "-1", "--format=%H", commit or "HEAD", "--", *([] if commit else [str(rel)])],
                            cwd=root, capture_output=True, text=True).stdout.strip()
    hashes = {p: input_hash_at(commit, p, root) for p in sorted(set(inputs))}
    page.write_text(with_block(page.read_text(), block(commit, hashes)))


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="list the pages whose inputs changed (exit 1 if any)")
    ap.add_argument("--mark-stale", nargs=2, metavar=("PAGE", "REASON"), help="mark a page stale")
    args = ap.parse_args(argv)
    if args.mark_stale:
        mark_stale(*args.mark_stale)
        return 0
    bad = 0
    for page in sorted(RESULTS.glob("*.md")):
        if page.name == "README.md":   # the index of the pages
            continue
        info = parse(page.read_text())
        moved = changed(page)
        if info is None:
            print(f"{page.relative_to(ROOT)}: no provenance block")
            bad += 1
        elif moved:
            bad += info["stale"] is None
            what = ", ".join(f"{p} ({a} -> {b})" for p, (a, b) in moved.items())
            print(f"{page.relative_to(ROOT)}: {'marked stale' if info['stale'] else 'STALE'}: {what}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
