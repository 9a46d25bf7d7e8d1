"""Regenerate docs/results/imu_gps_mag_anywhere.md and docs/results/ultrasonic_3d_anywhere.md (issue 31: the
shipped configs of papers 002 and 003 on recordings of other places, dates, headings and receiver numberings).

    python experiments/anywhere_results.py               # 5 seeds (~2 min on one core)
    python experiments/anywhere_results.py --seeds 1     # a quick look

Paper 002: scenarios/car_gps_mag.yaml moved to four places (both hemispheres, inclinations -64 to +82 deg)
and dates, its route turned so that the car starts facing each of four headings, cut to its first three legs
(167 s: 40 s static, then driving) without its GPS faults and disturbed field (so errors are "outside GPS
outages"), the magnetometer's field the IGRF there (the simulator's); replayed through the shipped
configs/imu_gps_mag_ekf.yaml unchanged (no field in it: the recording's header gives it) and once more with the
header's field line removed (the IGRF at the header's origin and date). Then the whole route at Seattle with no
magnetometer at all, from starts of 70 and 150 deg, through the shipped config and the paper's variant (no
renormalisation, the quat_norm pseudo-observation of eq. 9); errors after 90 s (50 s of driving).

Paper 003: scenarios/variants/ultrasonic_3d_walk_renumbered.yaml (the walk of Table III with the receivers
numbered in another order, listed in the header) through the shipped configs/ultrasonic_3d_pose.yaml, over
seeds, against the same walks in the paper's numbering.
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "world"))
from world_helpers import car_at  # noqa: E402  (the scenario the tests run, moved and turned)

MAG_CONFIG = ROOT / "configs" / "imu_gps_mag_ekf.yaml"
POSE_CONFIG = ROOT / "configs" / "ultrasonic_3d_pose.yaml"
OUT_002 = ROOT / "docs" / "results" / "imu_gps_mag_anywhere.md"
OUT_003 = ROOT / "docs" / "results" / "ultrasonic_3d_anywhere.md"
INPUTS = ("configs/imu_gps_mag_ekf.yaml", "configs/ultrasonic_3d_pose.yaml", "scenarios/car_gps_mag.yaml",
          "scenarios/ultrasonic_3d_walk.yaml", "scenarios/variants/ultrasonic_3d_walk_renumbered.yaml")

PLACES = [   # (name, lat deg, lon deg, height m, date)
    ("Seattle", 47.61, -122.33, 50.0, "2024-05-01T10:00:00"),
    ("Sydney", -33.87, 151.21, 20.0, "2019-11-20T01:00:00"),
    ("Longyearbyen", 78.22, 15.65, 10.0, "2021-03-01T10:00:00"),
    ("Sao Jose dos Campos", -23.21, -45.876, 600.0, "2008-06-10T14:00:00"),
]
HEADINGS = (0.0, 70.0, 160.0, -110.0)
PAPER = {"process": {"renormalize": False}, "sensors": {"qnorm": {"model": {"type": "quat_norm", "sd": 1e-3}}}}


def car_scenario(dest: Path, place: tuple, heading: float, seed: int, legs: int, magnetometer: bool) -> Path:
    """scenarios/car_gps_mag.yaml at ``place``, turned to ``heading`` (deg), its first ``legs`` legs: the
    scenario the tests of tests/world run (world_helpers.car_at)."""
    _, lat, lon, h, date = place
    return car_at(dest, lat, lon, h, date, heading, legs=legs, magnetometer=magnetometer, seed=seed)


def simulate(scenario: Path, log: Path, seed: int | None = None) -> Path:
    from fusion.simulate import simulate_file

    log.write_text(simulate_file(str(scenario), seed=seed))
    return log


def config(dest: Path, base: Path, merge: dict | None = None, settle: float | None = None) -> Path:
    """``base`` with ``merge`` merged in (dicts deep), its recording made absolute."""
    d = yaml.safe_load(base.read_text())
    d["recording"] = str((base.parent / d["recording"]).resolve())

    def deep(a: dict, b: dict) -> None:
        for k, v in b.items():
            if isinstance(v, dict) and isinstance(a.get(k), dict):
                deep(a[k], v)
            else:
                a[k] = v
    deep(d, merge or {})
    if settle is not None:
        d["evaluation"] = {"settle_s": settle}
    dest.write_text(yaml.safe_dump(d, sort_keys=False))
    return dest


def run(cfg: Path, log: Path, tmp: Path) -> dict:
    from fusion.cli import main

    out = tmp / "summary.json"
    code = main(["run", str(cfg), "--input", str(log), "-q", "--no-progress", "--force", "--summary-json", str(out)])
    s = json.loads(out.read_text())
    s["exit"] = code
    return s


def horizontal(s: dict) -> float:
    el = s["errors"]["element_rmse"]
    return math.hypot(el["px"], el["py"])


def paper002(seeds: list[int], tmp: Path) -> dict:
    shipped = config(tmp / "shipped.yaml", MAG_CONFIG)
    rows, igrf, nomag = [], [], []
    for place in PLACES:
        for heading in HEADINGS:
            for seed in seeds:
                log = simulate(car_scenario(tmp / "s.yaml", place, heading, seed, 3, True), tmp / "d.log")
                s = run(shipped, log, tmp)
                rows.append({"place": place[0], "heading": heading, "seed": seed, "exit": s["exit"],
                             "h": horizontal(s), "att": s["errors"]["attitude_rmse_deg"],
                             "att_max": s["errors"]["attitude_max_deg"],
                             "field": s["info"]["mag"]["measurement"]["reference_field"]})
                if heading == HEADINGS[1]:      # the same drive without the header's field: the IGRF
                    stripped = tmp / "igrf.log"
                    stripped.write_text("".join(ln for ln in log.read_text().splitlines(True)
                                                if "earth_field_ned" not in ln))
                    s = run(shipped, stripped, tmp)
                    igrf.append({"place": place[0], "seed": seed, "exit": s["exit"], "h": horizontal(s),
                                 "att": s["errors"]["attitude_rmse_deg"],
                                 "field": s["info"]["mag"]["measurement"]["reference_field"]})
    variants = {"shipped": config(tmp / "ns.yaml", MAG_CONFIG, settle=90.0),
                "paper (eq. 9, no renormalisation)": config(tmp / "np.yaml", MAG_CONFIG, PAPER, settle=90.0)}
    for heading in (70.0, 150.0):
        for seed in seeds:
            log = simulate(car_scenario(tmp / "s.yaml", PLACES[0], heading, seed, 7, False), tmp / "n.log")
            for name, cfg in variants.items():
                s = run(cfg, log, tmp)
                nomag.append({"variant": name, "heading": heading, "seed": seed, "exit": s["exit"],
                              "h": horizontal(s), "att": s["errors"]["attitude_rmse_deg"],
                              "att_max": s["errors"]["attitude_max_deg"],
                              "nees": s["consistency"]["nees_mean"], "resets": s["health"].get("resets", 0),
                              "start": s["info"]["mag"]["measurement"].get("start", "")})
    return {"rows": rows, "igrf": igrf, "nomag": nomag}


def paper003(seeds: list[int], tmp: Path) -> list[dict]:
    out = []
    variant = ROOT / "scenarios" / "variants" / "ultrasonic_3d_walk_renumbered.yaml"
    for seed in seeds:
        for name, sc in (("renumbered (header)", variant), ("paper's numbering", ROOT / "scenarios" / "ultrasonic_3d_walk.yaml")):
            d = yaml.safe_load(sc.read_text())
            d["trajectory"]["seed"] = seed
            (tmp / "w.yaml").write_text(yaml.safe_dump(d, sort_keys=False))
            log = simulate(tmp / "w.yaml", tmp / "w.log", seed)
            s = run(config(tmp / "pose.yaml", POSE_CONFIG), log, tmp)
            out.append({"walk": name, "seed": seed, "exit": s["exit"], "att": s["errors"]["attitude_rmse_deg"],
                        "att_max": s["errors"]["attitude_max_deg"], "pos": s["errors"]["position_rmse_m"],
                        "receivers": s["info"]["us"]["measurement"]["receiver_array"]})
    return out


def _ms(v) -> str:
    v = np.asarray(v, float)
    return f"{v.mean():.2f} ± {v.std():.2f}" if len(v) > 1 else f"{v[0]:.2f}"


def page002(r: dict, seeds: list[int], minutes: float) -> str:
    L = ["# Paper 002 anywhere: the shipped config at other places, dates and headings (issue 31)\n",
         f"Regenerate: `python experiments/anywhere_results.py` ({len(seeds)} seeds, {minutes:.1f} min on one core; "
         "also writes docs/results/ultrasonic_3d_anywhere.md).\n",
         "Each drive is scenarios/car_gps_mag.yaml moved to the place and date below, its route turned so the car "
         "starts facing the heading, cut to its first three legs (167 s: the 40 s static start, then ~127 s of "
         "driving) without the GPS faults and the disturbed field, so every error is outside a GPS outage. The "
         "simulated magnetometer sees the IGRF field of the place (fusion.geomag). The config is "
         "configs/imu_gps_mag_ekf.yaml unchanged: no field, no heading in it; the field comes from the "
         "recording's header (`# mag earth_field_ned`), the attitude from Improved TRIAD over the static start. "
         "Errors from the run's summary (every estimate after the start at 39 s); mean ± sd over seeds.\n",
         "## With the magnetometer: every place and heading\n",
         "Paper 002's accuracy on the shipped recording: horizontal position within 2 m RMSE, attitude within "
         "2 deg RMSE.\n",
         "| place | field (IGRF) | start heading (deg) | horiz. RMSE (m) | attitude RMSE (deg) | attitude max (deg) | exit |",
         "|---|---|---|---|---|---|---|"]
    for place in PLACES:
        for heading in HEADINGS:
            rs = [x for x in r["rows"] if x["place"] == place[0] and x["heading"] == heading]
            L.append(f"| {place[0]} | {rs[0]['field']['field']} | {heading:+.0f} | {_ms([x['h'] for x in rs])} | "
                     f"{_ms([x['att'] for x in rs])} | {_ms([x['att_max'] for x in rs])} | "
                     f"{','.join(sorted({str(x['exit']) for x in rs}))} |")
    worst_h = max(x["h"] for x in r["rows"])
    worst_a = max(x["att"] for x in r["rows"])
    L += ["", f"Worst run: horizontal {worst_h:.2f} m, attitude {worst_a:.2f} deg RMSE (bars: 2 m, 2 deg).\n",
          "## The field from the IGRF (no field line in the header)\n",
          "The 70 deg drives again with the header's `# mag earth_field_ned` line removed: the magnetometer takes "
          "the IGRF-14 field (ppigrf) at the header's `# origin` and `# start_utc` (the summary's "
          "`info.mag.measurement.reference_field` says so).\n",
          "| place | source | horiz. RMSE (m) | attitude RMSE (deg) | exit |", "|---|---|---|---|---|"]
    for place in PLACES:
        rs = [x for x in r["igrf"] if x["place"] == place[0]]
        L.append(f"| {place[0]} | {rs[0]['field']['source']} | {_ms([x['h'] for x in rs])} | "
                 f"{_ms([x['att'] for x in rs])} | {','.join(sorted({str(x['exit']) for x in rs}))} |")
    L += ["", "## No magnetometer at all\n",
          "The whole route at Seattle with no magnetometer line in the recording. The alignment levels roll and "
          "pitch from gravity and leaves the heading unknown (sd 104 deg about the config's starting guess; the "
          "summary's `info` says so); the GPS velocity must find it once the car moves. Errors after 90 s (50 s "
          "of driving); NEES on 21 dof.\n",
          "| variant | start heading (deg) | horiz. RMSE (m) | attitude RMSE (deg) | attitude max (deg) | NEES | "
          "resets | seeds within 2 deg |",
          "|---|---|---|---|---|---|---|---|"]
    within = {}
    for heading in (70.0, 150.0):
        for name in ("shipped", "paper (eq. 9, no renormalisation)"):
            rs = [x for x in r["nomag"] if x["variant"] == name and x["heading"] == heading]
            k = sum(x["att"] <= 2.0 for x in rs)
            within[name, heading] = (k, len(rs))
            L.append(f"| {name} | {heading:.0f} | {_ms([x['h'] for x in rs])} | {_ms([x['att'] for x in rs])} | "
                     f"{_ms([x['att_max'] for x in rs])} | {_ms([x['nees'] for x in rs])} | "
                     f"{_ms([x['resets'] for x in rs])} | {k} of {len(rs)} |")
    (a, n), (b, _), (c, _), (d, _) = (within[v, h] for h in (70.0, 150.0)
                                      for v in ("shipped", "paper (eq. 9, no renormalisation)"))
    L += ["", f"From a 70 deg start the shipped EKF finds the heading from the GPS velocity in {a} of {n} seeds, "
          f"the paper's variant in {b}; from 150 deg in {c} and {d}. Where it fails, the linearised update could "
          "not bridge the heading error (the gps recovery resets the position, not the heading). An explicit "
          "heading from the GPS course once moving (a reset of the heading rather than its slow correction) is "
          "not implemented yet (issue 31's fallback).\n"]
    return "\n".join(L)


def page003(r: list[dict], seeds: list[int], minutes: float) -> str:
    L = ["# Paper 003 anywhere: the pose config on a renumbered receiver array (issue 31)\n",
         f"Regenerate: `python experiments/anywhere_results.py` ({len(seeds)} seeds, {minutes:.1f} min with the paper-002 "
         "page, docs/results/imu_gps_mag_anywhere.md).\n",
         "scenarios/variants/ultrasonic_3d_walk_renumbered.yaml is the Monte-Carlo walk of Table III "
         "(scenarios/ultrasonic_3d_walk.yaml, 300 s) with the 32 receivers wired in another order; its header lists "
         "them (`# receiver N: x y z`). configs/ultrasonic_3d_pose.yaml names no array and reads it from the "
         "header. Each seed draws the walk and the noise; the same walk in the paper's numbering beside it. "
         "Table III (EKF): mean 9.34 deg, max 21.1 deg; the summary gives the RMSE (>= the mean).\n",
         "| walk | receiver array from | attitude RMSE (deg) | attitude max (deg) | position RMSE (m) | exit |",
         "|---|---|---|---|---|---|"]
    for name in ("renumbered (header)", "paper's numbering"):
        rs = [x for x in r if x["walk"] == name]
        L.append(f"| {name} | {rs[0]['receivers']['source']} | {_ms([x['att'] for x in rs])} | "
                 f"{_ms([x['att_max'] for x in rs])} | {_ms([x['pos'] for x in rs])} | "
                 f"{','.join(sorted({str(x['exit']) for x in rs}))} |")
    L += ["", "A config that names the paper's numbering (`receivers: truncated_icosahedron`) against this header is "
          "refused with exit 2 (fusion.header_checks), unless it says `prefer: {receivers: config}`.\n"]
    return "\n".join(L)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args(argv)
    seeds = list(range(1, args.seeds + 1))
    t0 = time.process_time()
    with tempfile.TemporaryDirectory() as d:
        r002 = paper002(seeds, Path(d))
        r003 = paper003(seeds, Path(d))
    minutes = (time.process_time() - t0) / 60.0
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import provenance

    provenance.write_page(OUT_002, page002(r002, seeds, minutes), INPUTS)
    provenance.write_page(OUT_003, page003(r003, seeds, minutes), INPUTS)
    print(f"wrote {OUT_002} and {OUT_003} ({minutes:.1f} min)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
