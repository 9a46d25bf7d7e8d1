"""Range simulator: one range to a beacon a message (UWB radio or ultrasonic time of flight)."""
from __future__ import annotations


import numpy as np
from pydantic import Field

from fusion.api import ConfigError
from fusion.simulate.base import SensorOutput, SensorSimulator, SimContext, SimParams, sample_times


class RangeParams(SimParams):
    rate_hz: float = Field(10.0, gt=0, description="cycles per second; a cycle ranges each beacon once")
    beacons: list[str] | None = Field(None, description="beacons ranged, in cycle order (default: all)")
    spacing_s: float | None = Field(None, gt=0, description="seconds between the ranges of a cycle "
                                                           "(default: the cycle spread evenly)")
    start_s: float = Field(0.0, ge=0, description="time of the first cycle (s)")
    noise_sd: float = Field(0.1, ge=0, description="range noise sd (m)")
    bias: float = Field(0.0, description="constant range bias (m)")
    outlier_prob: float = Field(0.0, ge=0, le=1, description="probability a range is an outlier")
    outlier_min: float = Field(0.3, description="an outlier adds U(outlier_min, outlier_max) m (a longer, "
                                                "reflected path)")
    outlier_max: float = Field(2.0, description="see outlier_min (m)")
    dropout_prob: float | dict[str, float] = Field(0.0, description="probability a range is missing; one "
                                                                   "value or per beacon {B1: 0.1}")
    max_range: float | None = Field(None, gt=0, description="no range beyond this distance (m)")
    lever_arm: list[float] = Field([0.0, 0.0, 0.0], description="receiver offset in the body frame (m, FRD)")
    speed_of_sound: float | None = Field(None, gt=0, description="m/s: time-of-flight ranging, the message "
                                         "time is the arrival time of a pulse emitted at the cycle slot and "
                                         "the range the distance then (None: instantaneous radio ranging)")


class RangeSimulator(SensorSimulator):
    """Ranges to beacons, one a line: fields ``beacon range`` (label, m).

    Each cycle (``rate_hz``) ranges the listed beacons in order, ``spacing_s`` apart. The true range is from
    the receiver (body origin + C_b^n lever_arm) to the beacon, in the plane for a 2-D scenario. Errors:
    Gaussian noise, a bias, outliers (a longer path, probability ``outlier_prob``), dropouts, a maximum
    range. With ``speed_of_sound`` the range is an ultrasonic time of flight: the pulse leaves the beacon at
    the slot time and the message is stamped when it arrives. ``--noise off`` removes noise, bias and
    outliers (dropouts and the range limit stay).
    """

    name = "range"
    Params = RangeParams

    def fields(self, sim: SimContext) -> tuple[str, ...]:
        return ("beacon", "range")

    def _beacons(self, sim: SimContext) -> list[str]:
        names = self.params.beacons if self.params.beacons is not None else list(sim.beacons)
        unknown = [b for b in names if b not in sim.beacons]
        if unknown:
            raise ConfigError(f"sensors.{self.context.sensor}.beacons: unknown beacon(s) {unknown}; the scenario "
                              f"defines {list(sim.beacons)}")
        if not names:
            raise ConfigError(f"sensors.{self.context.sensor}: no beacons (define `beacons:` in the scenario)")
        return names

    def header(self, sim: SimContext) -> list[str]:
        p = self.params
        return [f"{self.context.sensor} range_noise_sd: {p.noise_sd if sim.noise else 0.0}"]

    def receiver_position(self, sim: SimContext, t: np.ndarray) -> np.ndarray:
        kin = sim.kinematics(t)
        arm = np.asarray(self.params.lever_arm, float)
        pos = kin.p + (kin.rotation.apply(arm) if np.any(arm) else 0.0)
        if sim.dim == 2:
            pos = pos.copy()
            pos[:, 2] = 0.0
        return pos

    def simulate(self, sim: SimContext) -> SensorOutput:
        p = self.params
        names = self._beacons(sim)
        nb = len(names)
        spacing = p.spacing_s if p.spacing_s is not None else 1.0 / (p.rate_hz * nb)
        cycles = sample_times(p.rate_hz, sim.duration, p.start_s)
        t_slot = (cycles[:, None] + spacing * np.arange(nb)[None, :]).ravel()
        idx = np.tile(np.arange(nb), len(cycles))
        B = np.array([sim.beacons[n] for n in names])[idx]
        if sim.dim == 2:
            B = B.copy()
            B[:, 2] = 0.0
        t_msg = t_slot.copy()
        if p.speed_of_sound is not None:
            for _ in range(6):  # fixed point t = t_slot + |r(t) - b| / c, contraction factor |v| / c
                t_msg = t_slot + np.linalg.norm(self.receiver_position(sim, t_msg) - B, axis=1) / p.speed_of_sound
        rng_drop, rng_noise, rng_out = sim.rng.spawn(3)
        rng_out2 = rng_out.spawn(1)[0]
        true = np.linalg.norm(self.receiver_position(sim, t_msg) - B, axis=1)
        drop_p = (np.array([p.dropout_prob.get(n, 0.0) for n in names])[idx]
                  if isinstance(p.dropout_prob, dict) else np.full(len(idx), p.dropout_prob))
        keep = (rng_drop.random(len(idx)) >= drop_p) & (t_msg <= sim.duration)
        if p.max_range is not None:
            keep &= true <= p.max_range
        meas = true.copy()
        if sim.noise:
            meas += p.bias + rng_noise.normal(0.0, p.noise_sd, len(idx))
            out = rng_out.random(len(idx)) < p.outlier_prob
            meas += np.where(out, rng_out2.uniform(p.outlier_min, p.outlier_max, len(idx)), 0.0)
            meas = np.abs(meas)
        labels = np.array(names, dtype=object)[idx]
        k = np.flatnonzero(keep)
        return SensorOutput(t_msg[k], [(labels[i], float(meas[i])) for i in k])

    def rate_hz(self) -> float:
        return self.params.rate_hz
