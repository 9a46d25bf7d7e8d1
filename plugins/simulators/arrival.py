"""Ultrasonic arrival-time simulator (paper 003): beacons fire in sequence, a spherical receiver array
reports each pulse's arrival time and its closest receiver."""
from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field

from fusion.simulate.base import SensorOutput, SensorSimulator, SimContext, SimParams

_PHI = (1.0 + np.sqrt(5.0)) / 2.0


def _cyclic(v) -> list[tuple[float, float, float]]:
    a, b, c = v
    return [(a, b, c), (c, a, b), (b, c, a)]


def truncated_icosahedron_normals() -> np.ndarray:
    """The 32 outward face normals (32, 3) of a truncated icosahedron, unit length, body frame.

    Receivers 1-12 are the pentagons (the 12 icosahedron vertices: cyclic permutations of (0, +-1, +-phi)),
    receivers 13-32 the hexagons (the 20 icosahedron face centres: (+-1, +-1, +-1) and the cyclic
    permutations of (0, +-phi, +-1/phi)), each group in the order generated here. Adjacent receivers are
    37.4 deg (hexagon-pentagon) or 41.8 deg (hexagon-hexagon) apart, as in paper 003.
    """
    pent, hexa = [], []
    for s1 in (1, -1):
        for s2 in (1, -1):
            pent += _cyclic((0.0, s1 * 1.0, s2 * _PHI))
    for sx in (1, -1):
        for sy in (1, -1):
            for sz in (1, -1):
                hexa.append((sx, sy, sz))
    for s1 in (1, -1):
        for s2 in (1, -1):
            hexa += _cyclic((0.0, s1 * _PHI, s2 / _PHI))
    n = np.array(pent + hexa, float)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


RECEIVER_NORMALS = truncated_icosahedron_normals()


class ArrivalParams(SimParams):
    period_s: float = Field(0.225, gt=0, description="inter-firing period T (s): beacons fire in turn, one "
                                                     "every T (paper 003: a cycle of 4 every 900 ms)")
    first_fire_s: float = Field(0.137, ge=0, description="time the first beacon fires (s), unknown to the "
                                                         "receiver")
    period_drift: float = Field(0.0, description="relative error of the true period (the clock of the beacons), "
                                                 "e.g. 2e-5")
    beacons: list[str] | None = Field(None, description="firing order (default: all scenario beacons)")
    speed_of_sound: float = Field(340.0, gt=0, description="c (m/s); paper 003: 340 from the temperature")
    noise_sd: float = Field(2.0e-4, ge=0, description="arrival time noise sd (s); paper 003: 0.2 ms")
    echo_prob: float = Field(0.0, ge=0, le=1, description="probability an arrival is an echo (a longer path)")
    echo_min: float = Field(0.3, ge=0, description="an echo's extra path is U(echo_min, echo_max) m")
    echo_max: float = Field(3.0, ge=0, description="see echo_min (m)")
    max_range: float | None = Field(None, gt=0, description="no arrival beyond this distance (m)")
    dropout_prob: float = Field(0.0, ge=0, le=1, description="probability a pulse is missed")
    receivers: Literal["truncated_icosahedron"] | list[tuple[float, float, float]] = Field(
        "truncated_icosahedron", description="the receiver normals (body frame), receiver 1 first")
    renumber_seed: int | None = Field(None, description="number the receivers in a random order drawn with this "
                                      "seed (an array wired otherwise: the header lists the numbering)")


class ArrivalTimeSimulator(SensorSimulator):
    """Arrival times of ultrasonic pulses: fields ``beacon arrival receiver``.

    Beacon k of the firing order fires at ``t_f = first_fire_s + n T`` (n counts every firing, so beacon
    i fires at ``(i - 1) T + t_g`` within a cycle: paper 003 eq. 1); the pulse reaches the array when
    ``t_a = t_f + |p(t_a) - b| / c`` (solved by fixed point). The message time and the ``arrival`` value are
    the measured arrival time (s, receiver clock = log clock) with noise; an echo arrives later by its extra
    path / c and from a random direction. ``receiver`` is the index (1-32, or 1-k of ``receivers``) of the receiver whose face normal,
    rotated by the true attitude, is closest to the direction of the arriving pulse (the header lists the
    normals as ``# receiver N: x y z``, body frame). Truth adds ``T`` (the true firing period) and ``t_fire``
    (time of the latest firing). ``--noise off``: exact arrival times, no echoes.
    """

    name = "arrival_time"
    Params = ArrivalParams

    def fields(self, sim: SimContext) -> tuple[str, ...]:
        return ("beacon", "arrival", "receiver")

    def rate_hz(self) -> float:
        return 1.0 / self.params.period_s

    def header(self, sim: SimContext) -> list[str]:
        p = self.params
        s = self.context.sensor
        out = [f"{s} period_s: {p.period_s:g}", f"{s} speed_of_sound: {p.speed_of_sound:g}",
               f"{s} noise_sd: {p.noise_sd if sim.noise else 0:g}",
               f"{s} firing_order: {' '.join(self._order(sim))}"]
        out += [f"receiver {i + 1}: {n[0]:.9f} {n[1]:.9f} {n[2]:.9f}" for i, n in enumerate(self.normals())]
        return out

    def normals(self) -> np.ndarray:
        """The receivers' unit normals (k, 3), receiver r at row r - 1 (renumbered by ``renumber_seed``)."""
        p = self.params
        n = RECEIVER_NORMALS if isinstance(p.receivers, str) else np.asarray(p.receivers, float)
        n = n / np.linalg.norm(n, axis=1, keepdims=True)
        if p.renumber_seed is not None:
            n = n[np.random.default_rng(p.renumber_seed).permutation(len(n))]
        return n

    def _order(self, sim: SimContext) -> list[str]:
        from fusion.api import ConfigError
        names = self.params.beacons if self.params.beacons is not None else list(sim.beacons)
        bad = [b for b in names if b not in sim.beacons]
        if bad or not names:
            raise ConfigError(f"sensors.{self.context.sensor}.beacons: unknown or no beacons {bad}; the scenario "
                              f"defines {list(sim.beacons)}")
        return names

    def simulate(self, sim: SimContext) -> SensorOutput:
        p = self.params
        names = self._order(sim)
        T = p.period_s * (1.0 + (p.period_drift if sim.noise else 0.0))
        self._T = T
        n = int(np.floor((sim.duration - p.first_fire_s) / T)) + 1
        k = np.arange(max(n, 0))
        t_fire = p.first_fire_s + k * T
        idx = k % len(names)
        B = np.array([sim.beacons[b] for b in names])[idx]
        t_a = t_fire.copy()
        for _ in range(6):
            t_a = t_fire + np.linalg.norm(sim.kinematics(t_a).p - B, axis=1) / p.speed_of_sound
        kin = sim.kinematics(t_a)
        d = B - kin.p
        dist = np.linalg.norm(d, axis=1)
        u_b = kin.rotation.apply(d / dist[:, None], inverse=True)   # direction of the beacon, body frame
        r_drop, r_noise, r_echo, r_extra, r_dir = sim.rng.spawn(5)
        keep = r_drop.random(len(k)) >= p.dropout_prob
        if p.max_range is not None:
            keep &= dist <= p.max_range
        meas = t_a.copy()
        if sim.noise:
            meas += r_noise.normal(0.0, p.noise_sd, len(k))
            echo = r_echo.random(len(k)) < p.echo_prob
            meas += np.where(echo, r_extra.uniform(p.echo_min, p.echo_max, len(k)) / p.speed_of_sound, 0.0)
            rnd = r_dir.normal(size=(len(k), 3))
            u_b = np.where(echo[:, None], rnd / np.linalg.norm(rnd, axis=1, keepdims=True), u_b)
        receiver = np.argmax(u_b @ self.normals().T, axis=1) + 1
        keep &= meas <= sim.duration
        self._t_fire = t_fire
        sel = np.flatnonzero(keep)
        order = sel[np.argsort(meas[sel], kind="stable")]
        return SensorOutput(meas[order], [(names[idx[i]], float(meas[i]), str(int(receiver[i]))) for i in order])

    def truth_fields(self) -> tuple[str, ...]:
        return ("T", "t_fire")

    def truth(self, t: np.ndarray) -> np.ndarray:
        j = np.searchsorted(self._t_fire, t, side="right") - 1
        tf = np.where(j >= 0, self._t_fire[np.clip(j, 0, None)], np.nan)
        tf = np.where(j >= 0, tf, self._t_fire[0] - self._T)  # before the first firing: the virtual previous one
        return np.column_stack([np.full(len(t), self._T), tf])
