"""Compare the outputs of every shipped config (and two sweeps) before and after a change of the run loop.

    python scripts/compare_runs.py record /tmp/before      # on the old code
    python scripts/compare_runs.py record /tmp/after       # on the new code
    python scripts/compare_runs.py diff /tmp/before /tmp/after

(To record another commit's code with this checkout's configs: ``PYTHONPATH=/path/to/its/worktree``.)

``record`` runs ``fusion run CONFIG --output DIR/NAME.csv --summary-json DIR/NAME.json`` for each
configs/*.yaml and ``fusion sweep --engine serial --seeds 5`` on configs/uwb_pv_ukf.yaml and
configs/ultrasonic_3d_iekf.yaml. ``diff`` requires the estimate CSVs to be byte-identical, the summaries
identical less their timings (``wall_s``, ``us_per_predict``, ``us_per_update``), the exit codes equal, the
event lines on stderr equal, and the sweep rows equal less ``wall_s``; it prints each difference and exits 1
when there is one.
"""
from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TIMINGS = frozenset(("wall_s", "us_per_predict", "us_per_update"))
SWEEPS = {"sweep_uwb": "configs/uwb_pv_ukf.yaml", "sweep_us": "configs/ultrasonic_3d_iekf.yaml"}


#: One BLAS thread and one hash seed: a multi-threaded BLAS sums in an order that varies from run to run (the
#: last digits of ultrasonic_3d_moving differ between two runs of the same code), and so does a set's order of
#: iteration with Python's random hash seed (the last digits of a seed of the ultrasonic_3d_iekf sweep).
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
       "PYTHONHASHSEED": "0"}


def record(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for config in sorted((ROOT / "configs").glob("*.yaml")):
        name = config.stem
        with open(out / f"{name}.stderr", "w") as err, open(out / f"{name}.stdout", "w") as std:
            rc = subprocess.call(["fusion", "run", str(config.relative_to(ROOT)), "--output", str(out / f"{name}.csv"),
                                  "--summary-json", str(out / f"{name}.json"), "--force"], cwd=ROOT, stdout=std,
                                 stderr=err, env=ENV)
        (out / f"{name}.rc").write_text(f"{rc}\n")
    for name, config in SWEEPS.items():
        target = out / f"{name}.csv"
        target.unlink(missing_ok=True)
        with open(out / f"{name}.stdout", "w") as std:
            rc = subprocess.call(["fusion", "sweep", config, "--seeds", "5", "--engine", "serial", "--no-progress",
                                  "-o", str(target)], cwd=ROOT, stdout=std, stderr=subprocess.STDOUT, env=ENV)
        (out / f"{name}.rc").write_text(f"{rc}\n")


def _without_timings(value):
    if isinstance(value, dict):
        return {k: _without_timings(v) for k, v in value.items() if k not in TIMINGS}
    if isinstance(value, list):
        return [_without_timings(v) for v in value]
    return value


def _paths(a, b, where=""):
    """The key paths where two JSON values differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            yield from _paths(a.get(k), b.get(k), f"{where}.{k}")
    elif a != b:
        yield f"{where}: {a!r} -> {b!r}"


def _sweep_rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return [{k: v for k, v in row.items() if k != "wall_s"} for row in csv.DictReader(f)]


def diff(before: Path, after: Path) -> int:
    problems: list[str] = []
    for rc in sorted(before.glob("*.rc")):
        name = rc.stem
        other = after / rc.name
        if not other.exists():
            problems.append(f"{name}: not recorded after")
            continue
        if rc.read_text() != other.read_text():
            problems.append(f"{name}: exit {rc.read_text().strip()} -> {other.read_text().strip()}")
        if name in SWEEPS:
            if _sweep_rows(before / f"{name}.csv") != _sweep_rows(after / f"{name}.csv"):
                problems.append(f"{name}: sweep rows differ (less wall_s)")
            continue
        for suffix in (".csv",):
            a, b = before / f"{name}{suffix}", after / f"{name}{suffix}"
            if a.exists() != b.exists() or (a.exists() and a.read_bytes() != b.read_bytes()):
                problems.append(f"{name}{suffix}: not byte-identical")
        a, b = before / f"{name}.json", after / f"{name}.json"
        if a.exists() and b.exists():
            ja, jb = (_without_timings(json.loads(p.read_text())) for p in (a, b))
            problems += [f"{name}.json{p}" for p in _paths(ja, jb)]
        elif a.exists() != b.exists():
            problems.append(f"{name}.json: present in one only")
        if (before / f"{name}.stderr").read_text() != (after / f"{name}.stderr").read_text():
            problems.append(f"{name}.stderr: the events told differ")
    for p in problems:
        print(p)
    print(f"{len(problems)} difference(s)")
    return 1 if problems else 0


def main(argv: list[str]) -> int:
    if len(argv) == 2 and argv[0] == "record":
        record(Path(argv[1]).resolve())
        return 0
    if len(argv) == 3 and argv[0] == "diff":
        return diff(Path(argv[1]), Path(argv[2]))
    print(__doc__, file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
