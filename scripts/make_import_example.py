"""Write the CSV dataset example of docs/import.md (docs/examples/uwb_dataset/) from a simulated recording.

    python scripts/make_import_example.py

It lays out the first 20 s of recordings/uwb_route1.log the way public UWB datasets are laid out, so that
`fusion import` has to undo every quirk: ranges.csv has ISO 8601 date-time stamps, one column per anchor in
millimetres, the cell of the anchor ranged in that row filled and the others empty (and a few dropouts
written NaN); mocap.csv is the motion-capture truth on its own clock (seconds from its own start, which
began 2.0 s before the radio's) with positions and velocities in metres. Importing with the mapping
docs/examples/uwb_dataset/mapping.yaml gives back the recording's lines (to 1 um and 1 us).
"""
from __future__ import annotations

import datetime as dt
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "recordings" / "uwb_route1.log"
OUT = ROOT / "docs" / "examples" / "uwb_dataset"
START = dt.datetime(2024, 3, 5, 10, 15, 2, 250000, tzinfo=dt.timezone.utc)  # the radio's first row
SPAN_S = 20.0
MOCAP_LEAD_S = 2.0      # the motion-capture clock started this long before the radio's first row
ANCHORS = ("B1", "B2", "B3", "B4")


def main() -> None:
    ranges, truth = [], []
    for line in SRC.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        parts = line.split(",")
        t = float(parts[0])
        if t > SPAN_S:
            break
        if parts[1] == "uwb":
            ranges.append((t, parts[2], float(parts[3])))
        elif parts[1] == "truth":
            truth.append((t, *map(float, parts[2:])))
    OUT.mkdir(parents=True, exist_ok=True)
    rows = ["timestamp,anchor_1_mm,anchor_2_mm,anchor_3_mm,anchor_4_mm,rssi_dbm"]
    for k, (t, b, r) in enumerate(ranges):
        stamp = (START + dt.timedelta(seconds=t)).isoformat(timespec="milliseconds").replace("+00:00", "Z")
        cells = [""] * 4
        cells[ANCHORS.index(b)] = f"{r * 1000:.3f}"
        rows.append(",".join([stamp, *cells, f"{-78 - (k % 7)}"]))
        if k in (57, 211):   # two dropouts: the radio logged a row without a range
            rows.append(",".join([stamp, "NaN", "", "", "", "-99"]))
    (OUT / "ranges.csv").write_text("\n".join(rows) + "\n")
    rows = ["# motion capture, 20 Hz, metres, seconds from the capture's start", "t,x,y,vx,vy"]
    rows += [f"{t + MOCAP_LEAD_S:.4f},{px:.6f},{py:.6f},{vx:.6f},{vy:.6f}" for t, px, py, vx, vy in truth]
    (OUT / "mocap.csv").write_text("\n".join(rows) + "\n")
    print(f"wrote {OUT}: {len(ranges)} ranges, {len(truth)} truth rows")


if __name__ == "__main__":
    main()
