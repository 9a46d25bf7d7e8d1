"""``initial.from_sensor`` is accepted only from a sensor whose measurement model can give the initial
position: one with the PositionFromFix capability (a position or GNSS fix, a solver's fix observed as a
position), or one whose first values are the position block itself (h selects ``p``: checked on h at the
initial mean by central differences, exact for a selection). Anything else (a range, a direction, a field)
would have its first value taken as a coordinate (the range to a beacon as the north position): a config
error naming the sensor and its model.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from fusion.api import PositionFromFix, has
from fusion.errors import ConfigError

#: step (state units) of the central differences; h of a selection is linear, so any step is exact
STEP = 1e-3
#: a selection's derivatives are 1 and 0 to rounding
TOLERANCE = 1e-6


def selects_position(model: Any, x0: np.ndarray, p: slice) -> bool:
    """Whether ``model.h`` at ``x0`` (n,) gives the position block ``p`` as its first values (False when h
    cannot be evaluated without a message, or has fewer values)."""
    k = p.stop - p.start
    x0 = np.asarray(x0, dtype=float)
    try:
        if len(np.atleast_1d(model.h(x0))) < k:
            return False
        H = np.empty((k, len(x0)))
        for j in range(len(x0)):
            e = np.zeros(len(x0))
            e[j] = STEP
            H[:, j] = (np.asarray(model.h(x0 + e), float)[:k] - np.asarray(model.h(x0 - e), float)[:k]) / (2 * STEP)
    except Exception:       # h needs a message first (a range bound to its beacon): not a position
        return False
    want = np.zeros_like(H)
    want[np.arange(k), p.start + np.arange(k)] = 1.0
    return bool(np.all(np.isfinite(H)) and np.max(np.abs(H - want)) < TOLERANCE)


def check_from_sensor(name: str | None, sensor: Any, layout: Any, x0: np.ndarray, where: str) -> None:
    """ConfigError at ``where`` unless sensor ``name``'s model can give the initial position (module doc)."""
    if name is None or sensor is None or sensor.model is None:
        return
    model = sensor.model
    if "p" not in layout:
        raise ConfigError(f"{where}: {name!r}: the state has no position block 'p' to initialise")
    if has(model, PositionFromFix) or selects_position(model, x0, layout["p"]):
        return
    raise ConfigError(f"{where}: sensor {name!r} (model {model.name!r}) cannot give the initial position: its "
                      f"measurement is not a position fix (its model has no position_from and h does not select "
                      f"the state's p); use a position or GNSS sensor, or a solver's fix observed by a position "
                      "model, or leave initial.from_sensor out")
