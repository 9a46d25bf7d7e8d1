"""Whether a recording's IMU can be dead-reckoned, from what its importer wrote in the header
(fusion.importers.coverage): ``# SENSOR_coverage_fraction: F`` (the share of the time the logged samples
integrate: a PX4 log written at 8.6 Hz keeps 4 ms of each ~116 ms) and ``# SENSOR_rotation_per_sample_deg: D``
(the largest rotation between two samples, |gyro| x spacing).

Below ``sensors.NAME.min_coverage`` of the time, or above ``sensors.NAME.max_rotation_deg`` a sample, the
input does not describe the motion between its samples: the integration is a guess there, whatever the
filter. ``fusion run`` then warns once and the summary's ``health`` has ``imu_coverage`` (the figures and
which limit they break), for a health rule to act on.
"""
from __future__ import annotations

import math
from typing import Any

#: Defaults of ``sensors.NAME.min_coverage`` and ``max_rotation_deg``: half of the motion missing is no
#: dead reckoning; 5 deg between samples keeps a held sample's attitude error (the coning/commutation
#: error of a rotation integrated from one rate, ~theta^2 / 12 rad a step) under 1e-3 rad a step.
MIN_COVERAGE = 0.5
MAX_ROTATION_DEG = 5.0


def _number(meta: dict[str, str], key: str) -> float | None:
    text = meta.get(key)
    if text is None:
        return None
    try:
        v = float(str(text).split()[0])
    except (ValueError, IndexError):
        return None
    return v if math.isfinite(v) else None


def assess(sensor: str, meta: dict[str, str], min_coverage: float = MIN_COVERAGE,
           max_rotation_deg: float = MAX_ROTATION_DEG) -> tuple[dict[str, Any] | None, str | None]:
    """(facts for the summary's health or None when the header says nothing, a warning text or None) of the
    input ``sensor`` from the header ``meta``."""
    fraction = _number(meta, f"{sensor}_coverage_fraction")
    rotation = _number(meta, f"{sensor}_rotation_per_sample_deg")
    if fraction is None and rotation is None:
        return None, None
    facts: dict[str, Any] = {"fraction": fraction, "rotation_per_sample_deg": rotation,
                             "min_coverage": min_coverage, "max_rotation_deg": max_rotation_deg}
    why = []
    if fraction is not None and fraction < min_coverage:
        why.append(f"its samples integrate {fraction:.3g} of the time (min_coverage {min_coverage:g})")
    if rotation is not None and rotation > max_rotation_deg:
        why.append(f"it turns up to {rotation:.3g} deg between two samples (max_rotation_deg {max_rotation_deg:g})")
    facts["insufficient"] = bool(why)
    if not why:
        return facts, None
    return facts, ("IMU coverage: " + " and ".join(why) + ": the motion between its samples is not in "
                   "the recording, so the dead reckoning cannot be trusted (a log written at a low rate? log the "
                   "IMU at its full rate)")
