"""Shared helpers of the simulator tests."""
from __future__ import annotations

import numpy as np
import pytest

from fusion.logformat import ParsedStream, iter_messages
from fusion.simulate import parse_scenario, simulate


def run_yaml(text: str, seed: int | None = None, noise: bool = True) -> str:
    """Simulate scenario YAML text."""
    return simulate(parse_scenario(text, "test.yaml"), seed=seed, noise=noise, where="test.yaml", text=text)


def parse_log(text: str):
    """(messages by sensor: {sensor: [Message]}, header) of a log text; asserts nothing is malformed."""
    st = ParsedStream()
    out: dict[str, list] = {}
    for m in iter_messages(text.splitlines(), st):
        assert not isinstance(m, Exception), m
        out.setdefault(m.sensor, []).append(m)
    assert not st.malformed, st.last_error
    return out, st.header


def table(msgs) -> np.ndarray:
    """(N, 1 + k) array of time and numeric values."""
    return np.array([(m.t,) + tuple(m.values) for m in msgs], float)


@pytest.fixture
def yaml_3d_turning() -> str:
    """A 3-D vehicle: static start, turns of several radii, hills, a stop, a slow corner; 100 Hz IMU."""
    return """
name: turning
seed: 5
dim: 3
trajectory:
  type: waypoints
  speed: 3.0
  max_accel: 1.0
  radius: 4.0
  static_start: 3.0
  waypoints:
    - [0.0, 0.0, 0.0]
    - [40.0, 0.0, -2.0]
    - {at: [40.0, 30.0, -1.0], radius: 2.0, turn_speed: 1.5}
    - {at: [10.0, 35.0, 1.0], stop: 2.0}
    - [0.0, 10.0, 0.5]
    - [20.0, 5.0, 0.0]
sensors:
  imu:
    type: imu
    rate_hz: 100
"""
