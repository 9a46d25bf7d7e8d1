"""Broken cases built from shipped configs and recordings, each a run whose estimate cannot be trusted
(issue 28 item 2): the config or recording is written to a temporary folder with one thing changed."""
from __future__ import annotations

import random
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]


def config(tmp: Path, name: str, edit, out: str, recording: Path | None = None) -> Path:
    """configs/NAME with ``edit(dict)`` applied, its recording an absolute path (or ``recording``)."""
    data = yaml.safe_load((ROOT / "configs" / name).read_text(encoding="utf-8"))
    data["recording"] = str(recording or (ROOT / "configs" / data["recording"]).resolve())
    edit(data)
    path = tmp / out
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def wrong_field(tmp: Path) -> Path:
    """Paper 002's config with the field of another hemisphere (WMM at -35.4, 149.2: the recording's is
    declination -20.5 deg, inclination -36 deg, 23.5 uT): most magnetometer updates are rejected."""
    def edit(d):
        d["sensors"]["mag"]["model"].update(declination_deg=12.3, inclination_deg=65.8, intensity=57.6)
        d["prefer"] = {"magnetic_field": "config"}   # else the recording's header contradicts it: exit 2
    return config(tmp, "imu_gps_mag_ekf.yaml", edit, "wrong_field.yaml")


def gps_latency(tmp: Path) -> Path:
    """The ArduPilot config on its recording with every GPS fix stamped 0.3 s before it was logged (a GPS
    latency the config does not know: its time_offset 0 s, a 0.1 s reorder buffer): every fix after the
    first is dropped as late. (A time_offset of -0.3 s in the config itself is refused by validation.)"""
    data = yaml.safe_load((ROOT / "configs" / "ardupilot_ins_gps_mag.yaml").read_text(encoding="utf-8"))
    source = (ROOT / "configs" / data["recording"]).resolve()
    lines = []
    for line in source.read_text(encoding="utf-8").splitlines():
        head, sep, rest = line.partition(",")
        if sep and rest.startswith("gps,"):
            line = f"{float(head) - 0.3:.6f},{rest}"
        lines.append(line)
    recording = tmp / "gps_latency.log"
    recording.write_text("\n".join(lines) + "\n", encoding="utf-8")

    def edit(d):
        d["sensors"]["gps"]["time_offset"] = 0.0
        d["scheduler"]["max_latency"] = 0.1
    return config(tmp, "ardupilot_ins_gps_mag.yaml", edit, "gps_latency.yaml", recording)


def wide_start(tmp: Path) -> Path:
    """The UWB config started 25 m from the walker with a 0.3 m sd: the gate rejects the ranges that would
    correct it (a lock-out)."""
    def edit(d):
        d["initial"]["mean"]["p"] = [25.0, 15.0]
        d["initial"]["sd"]["p"] = 0.3
    return config(tmp, "uwb_pv_ukf.yaml", edit, "wide_start.yaml")


def renumbered_receivers(tmp: Path, seed: int = 7) -> Path:
    """The paper 003 pose config on its recording with the closest-receiver numbers permuted (another
    numbering of the 32-receiver array than the header's)."""
    perm = list(range(1, 33))
    random.Random(seed).shuffle(perm)
    out = []
    for line in (ROOT / "recordings" / "ultrasonic_3d_walk.log").read_text(encoding="utf-8").splitlines():
        parts = line.split(",")
        if len(parts) == 5 and parts[1] == "us":
            parts[4] = str(perm[int(parts[4]) - 1])
            line = ",".join(parts)
        out.append(line)
    log = tmp / "walk_renumbered.log"
    log.write_text("\n".join(out) + "\n", encoding="utf-8")
    return config(tmp, "ultrasonic_3d_pose.yaml", lambda d: None, "renumbered.yaml", log)
