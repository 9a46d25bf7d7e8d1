"""Helpers of the tests of a config against its recording's world (tests/world): temp scenarios and configs
made from the shipped ones with a few values changed. (Not conftest.py: tests/health has its own, and
`from conftest import` would find whichever came first.)"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import yaml

from fusion.cli import main

ROOT = Path(__file__).resolve().parents[2]


def edited(src: Path, dest: Path, **changes: Any) -> Path:
    """``src`` (YAML) with top-level keys replaced (a dotted key sets a nested one), written to ``dest``."""
    data = yaml.safe_load(src.read_text())
    for key, value in changes.items():
        *path, last = key.split(".")
        node = data
        for k in path:
            node = node[k]
        if value is None:
            node.pop(last, None)
        else:
            node[last] = value
    dest.write_text(yaml.safe_dump(data, sort_keys=False))
    return dest


def simulate(scenario: Path, out: Path, seed: int | None = None) -> Path:
    args = ["simulate", str(scenario), "-o", str(out), "--force"]
    assert main(args + (["--seed", str(seed)] if seed is not None else [])) == 0
    return out


def run(config: Path, recording: Path | None, out: Path, *extra: str) -> tuple[int, dict | None]:
    args = ["run", str(config), "-q", "--no-progress", "--summary-json", str(out), "--force", *extra]
    code = main(args + (["--input", str(recording)] if recording is not None else []))
    return code, json.loads(out.read_text()) if out.exists() else None



def car_at(dest: Path, lat: float, lon: float, alt: float, date: str, heading_deg: float, legs: int = 3,
           magnetometer: bool = True, seed: int | None = None) -> Path:
    """scenarios/car_gps_mag.yaml moved to (lat, lon, alt m) on ``date``, its route turned by ``heading_deg``
    (the car starts facing that way), cut to its first ``legs`` legs, without the GPS faults and the
    disturbed field, the magnetometer's field left to the simulator (the IGRF there) or no magnetometer."""
    import math

    d = yaml.safe_load((ROOT / "scenarios" / "car_gps_mag.yaml").read_text())
    d["name"] = "car_gps_mag_elsewhere"
    d["origin"] = {"lat_deg": lat, "lon_deg": lon, "alt_m": alt}
    d["start_utc"] = date
    if seed is not None:
        d["seed"] = seed
    c, s = math.cos(math.radians(heading_deg)), math.sin(math.radians(heading_deg))

    def turned(w):
        if isinstance(w, dict):
            return {**w, "at": turned(w["at"])}
        return [w[0] * c - w[1] * s, w[0] * s + w[1] * c, w[2]]

    d["trajectory"]["waypoints"] = [turned(w) for w in d["trajectory"]["waypoints"][:legs + 1]]
    for k in ("lost_fixes", "gaps"):
        d["sensors"]["gps"].pop(k, None)
    for k in ("declination_deg", "inclination_deg", "intensity", "disturbances"):
        d["sensors"]["mag"].pop(k, None)
    if not magnetometer:
        d["sensors"].pop("mag")
    dest.write_text(yaml.safe_dump(d, sort_keys=False))
    return dest
