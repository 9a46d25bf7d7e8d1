"""Fuzz ``fusion run`` with mutated recordings; writes docs/results/fuzz_recordings.md.

Each trial takes one shipped config and its recording (cut to its first ``--until`` s so a trial takes
~0.1 s), picks a sensor (uniformly among those in the recording, truth included), one of its lines and
one mutation of fusion.fuzzing (bit flip, truncation, duplicated/dropped/swapped field, extreme or
non-finite number, label, NUL, invalid UTF-8, random bytes, repeated line), and runs
``fusion run CONFIG --input MUTATED -q --summary-json S`` in process. It counts exit codes (1 must never
happen: an internal error) and, for exit 0, runs whose counters show lines the mutation did not touch
going missing (fusion.fuzzing.accounting_errors), and lists every exit-1 case with a reproducer.

    python experiments/fuzz_recordings.py                 # 1000 trials + 1000 configs, seed 0 (~5 min, one core)
    python experiments/fuzz_recordings.py -n 200 --configs 100 --seed 3 --out /tmp/fuzz.md

Then the page's section "Mutated configs": 1-3 line mutations of a shipped config (fusion.fuzzing.mutate_config),
``fusion validate``, and ``fusion run`` of those that pass; exit 1 must never happen there either.
"""
from __future__ import annotations

import argparse
import collections
import random
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fusion.config import load_system  # noqa: E402
from fusion.fuzzing import (CONFIG_OPS, OPS, Recording, accounting_errors, field_index, mutate,  # noqa: E402
                            mutate_config, run_cli)
import provenance  # noqa: E402  (experiments/, on the path: the page's provenance block)

#: The files the page is made from: their hashes go in its provenance block (experiments/provenance.py).
INPUTS = tuple(f"{kind}/{name}" for pair in (("abps_ins.yaml", "abps_mine.log"), ("uwb_pv_ukf.yaml", "uwb_route1.log"),
                                                ("example_2d.yaml", "example_2d.log"),
                                                ("uwb_pv_ukf_line.yaml", "uwb_route1_line.log"))
               for kind, name in zip(("configs", "recordings"), pair))

TARGETS = (("configs/abps_ins.yaml", "recordings/abps_mine.log"),
           ("configs/uwb_pv_ukf.yaml", "recordings/uwb_route1.log"),
           ("configs/example_2d.yaml", "recordings/example_2d.log"),
           ("configs/uwb_pv_ukf_line.yaml", "recordings/uwb_route1_line.log"))


def fuzz_configs(n: int, seed: int, work: Path, recs: dict) -> tuple[collections.Counter, list[str], list[str]]:
    """n mutated configs: validate, and run those that validate on the cut recordings."""
    import contextlib
    import io

    from fusion.cli import main as fusion

    rng = random.Random(seed + 1)
    texts = []
    for cfg, log in TARGETS:
        cut = work / Path(log).name
        cut.write_bytes(b"\n".join(recs[cfg].lines) + b"\n")
        texts.append((cfg, (ROOT / cfg).read_text().replace("../recordings/", f"{work}/")))
    codes: collections.Counter = collections.Counter()
    failures: list[str] = []
    refused: list[str] = []   # validated, then refused by the run: validate could have said so
    path = work / "config.yaml"
    for _ in range(n):
        name, text = texts[rng.randrange(len(texts))]
        edits = [(rng.choice(CONFIG_OPS), rng.randrange(1 << 16), rng.randrange(1 << 16))
                 for _ in range(rng.choice((1, 1, 2, 3)))]
        for op, i, j in edits:
            text = mutate_config(text, op, i, j)
        path.write_text(text)
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = fusion(["validate", str(path)])
            outcome = f"validate exit {code}"
            if code == 0:
                code = fusion(["run", str(path), "-q", "--no-progress"])
                outcome = f"validate exit 0, run exit {code}"
        codes[outcome] += 1
        last = (err.getvalue().strip().splitlines() or ["(no message)"])[-1][:300].replace(str(work), "<tmp>")
        if code == 1:
            failures.append(f"- `{name}` with {edits}: {last}")
        elif outcome == "validate exit 0, run exit 2":
            refused.append(f"- `{name}` with {edits}: {last}")
    return codes, failures, refused


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-n", type=int, default=1000, help="trials (default 1000)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--until", type=float, default=40.0, help="s of each recording replayed (default 40)")
    ap.add_argument("--configs", type=int, default=1000, help="mutated configs (default 1000)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "fuzz_recordings.md"))
    args = ap.parse_args(argv)
    rng = random.Random(args.seed)
    work = Path(tempfile.mkdtemp(prefix="fusion-fuzz-"))
    recs, bases, by_sensor, inputs = {}, {}, {}, {}
    for cfg, log in TARGETS:
        rec = Recording.read(ROOT / log, until_s=args.until)
        code, base, err = run_cli(ROOT / cfg, b"\n".join(rec.lines) + b"\n", work, "base")
        if code != 0:
            raise SystemExit(f"{cfg}: the unmutated recording gives exit {code}: {err}")
        recs[cfg], bases[cfg] = rec, base
        inputs[cfg] = [n for n, s in load_system(ROOT / cfg).sensors.items() if s.role == "input"]
        groups = collections.defaultdict(list)
        for n in rec.messages:
            groups[rec.sensor_of(n)].append(n)
        by_sensor[cfg] = groups
    codes: collections.Counter = collections.Counter()
    per_op: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    lost: list[str] = []
    failures: list[str] = []
    t0 = time.perf_counter()
    for trial in range(args.n):
        cfg, log = TARGETS[rng.randrange(len(TARGETS))]
        rec = recs[cfg]
        sensor = rng.choice(sorted(by_sensor[cfg]))
        index = rng.choice(by_sensor[cfg][sensor])
        op, i, j = rng.choice(OPS), rng.randrange(1 << 16), rng.randrange(1 << 16)
        line = rec.lines[index]
        new = mutate(line, op, i, j)
        code, summary, err = run_cli(ROOT / cfg, rec.with_line(index, new), work)
        kind = f"{op}(time)" if field_index(line, op, i) == 0 else op
        codes[code] += 1
        per_op[kind][code] += 1
        where = f"`{cfg}`, {log} line {index + 1} ({sensor}): `{line!r}` -> `{new[:120]!r}`"
        if code == 1:
            failures.append(f"- {where}: {err.strip().splitlines()[-1] if err.strip() else '(no message)'}")
        elif code == 0 and summary is not None:
            problems = accounting_errors(bases[cfg], summary, sensor, op, blank=not new.strip(),
                                         inputs=inputs[cfg])
            if problems:
                lost.append(f"- {where}: {'; '.join(problems)}")
    wall = time.perf_counter() - t0
    t1 = time.perf_counter()
    cfg_codes, cfg_failures, cfg_refused = fuzz_configs(args.configs, args.seed, work, recs)
    cfg_wall = time.perf_counter() - t1
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    text = [
        "# Fuzzing `fusion run` with mutated recordings",
        "",
        f"Generated by `python experiments/fuzz_recordings.py -n {args.n} --seed {args.seed} --until {args.until:g}` "
        f"({wall:.0f} s). One line of a shipped recording (its first {args.until:g} s) mutated per trial "
        "(fusion/fuzzing.py); configs and recordings: " + ", ".join(f"`{c}` + `{r}`" for c, r in TARGETS) + ".",
        "",
        "Exit codes (0: ran, 2: refused with one line, 1: internal error, never wanted):",
        "",
        "| exit | trials |", "|---|---|",
        *[f"| {c} | {codes[c]} |" for c in sorted(codes)],
        "",
        "By mutation (`(time)`: the mutation hit the time stamp):",
        "",
        "| mutation | exit 0 | exit 2 | exit 1 |", "|---|---|---|---|",
        *[f"| {k} | {v[0]} | {v[2]} | {v[1]} |" for k, v in sorted(per_op.items())],
        "",
        f"## Exit 1 ({len(failures)})",
        "",
        *(failures or ["None."]),
        "",
        f"## Exit 0 but lines the mutation did not touch went missing ({len(lost)})",
        "",
        "A sensor's `received` count differs from the unmutated run by more than the mutated line, or the "
        "input sensor (IMU) did not use every sample it used unmutated (fusion.fuzzing.accounting_errors).",
        "",
        *(lost or ["None."]),
        "",
        "## Mutated configs",
        "",
        f"{args.configs} configs ({cfg_wall:.0f} s): a shipped config with 1-3 line mutations (fusion.fuzzing."
        "mutate_config: a value replaced by a non-finite, overflowing, mistyped or bomb value, a line deleted, "
        "duplicated, cut, bit-flipped, indented or swapped); `fusion validate`, then, when it passes, `fusion run` "
        f"on the first {args.until:g} s of the recording.",
        "",
        "| outcome | configs |", "|---|---|",
        *[f"| {k} | {v} |" for k, v in sorted(cfg_codes.items())],
        "",
        f"### Exit 1 ({len(cfg_failures)})",
        "",
        *(cfg_failures or ["None."]),
        "",
        f"### Validated, then refused by the run ({len(cfg_refused)})",
        "",
        *(cfg_refused or ["None."]),
        "",
    ]
    provenance.write_page(out, "\n".join(text), INPUTS)
    print(f"{args.n} trials in {wall:.0f} s: exit codes {dict(sorted(codes.items()))}; {len(lost)} with lines lost; "
          f"{args.configs} configs: {dict(sorted(cfg_codes.items()))}; written to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
