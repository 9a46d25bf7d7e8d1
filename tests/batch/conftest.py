"""Shared fixtures of the batched-filter tests: the UWB system (4-state pv + range) and a 16-state INS
with a 3-range measurement."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fusion.api import MeasurementModel, Message

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def uwb():
    from fusion.config import load_system

    return load_system(ROOT / "configs" / "uwb_pv_ukf.yaml")


def bound_range(system, beacon: str):
    """The range model bound to one beacon, as the scheduler gets it from a message."""
    return system.sensors["uwb"].model.observe(Message(0.0, "uwb", (beacon, 1.0), 0)).model


class Ranges3D(MeasurementModel):
    """Ranges (m) from the INS position p (NED) to three fixed points: a non-linear 3-vector."""

    name = "test_ranges3d"
    dim = 3
    B = np.array([[10.0, 0.0, -2.0], [0.0, 12.0, -1.0], [-8.0, -6.0, -3.0]])

    def h(self, x):
        d = x[..., None, 0:3] - self.B
        return np.sqrt((d * d).sum(axis=-1))

    def jacobian(self, x):
        d = x[0:3] - self.B
        H = np.zeros((3, x.shape[-1]))
        H[:, 0:3] = d / np.sqrt((d * d).sum(axis=-1))[:, None]
        return H


@pytest.fixture(scope="module")
def ranges3d():
    return Ranges3D()
