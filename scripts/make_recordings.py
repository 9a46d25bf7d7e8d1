#!/usr/bin/env python3
"""Regenerate the shipped recordings: recordings/NAME.log from every scenarios/NAME.yaml.

    python scripts/make_recordings.py            # rewrite all recordings
    python scripts/make_recordings.py abps_mine  # only these scenarios
    python scripts/make_recordings.py --check    # exit 1 if a recording differs from its scenario's output

Each recording is exactly ``fusion simulate scenarios/NAME.yaml -o recordings/NAME.log`` (the scenario's
own seed, noise on); the same scenario and seed always give the same bytes.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def scenario_files(names: list[str] | None = None) -> list[Path]:
    files = sorted((ROOT / "scenarios").glob("*.yaml"))
    if names:
        wanted = {Path(n).stem for n in names}
        missing = wanted - {f.stem for f in files}
        if missing:
            raise SystemExit(f"no scenario {sorted(missing)} in {ROOT / 'scenarios'}")
        files = [f for f in files if f.stem in wanted]
    return files


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("names", nargs="*", help="scenario names (default: all in scenarios/)")
    ap.add_argument("--check", action="store_true", help="compare instead of writing; exit 1 on a difference")
    args = ap.parse_args(argv)
    from fusion.simulate import simulate_file

    out_dir = ROOT / "recordings"
    out_dir.mkdir(exist_ok=True)
    bad = 0
    total = 0
    for sc in scenario_files(args.names):
        text = simulate_file(str(sc))
        data = text.encode("utf-8")
        total += len(data)
        dest = out_dir / f"{sc.stem}.log"
        if args.check:
            same = dest.exists() and dest.read_bytes() == data
            bad += not same
            print(f"{'ok  ' if same else 'DIFF'} {dest.relative_to(ROOT)}")
        else:
            dest.write_bytes(data)
            print(f"wrote {dest.relative_to(ROOT)} ({len(data) / 1e6:.2f} MB)")
    print(f"total {total / 1e6:.2f} MB")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
