"""``fusion tui --udp HOST:PORT``: every estimate as one JSON object a UDP datagram, for PlotJuggler.

The shape PlotJuggler's UDP server reads with the JSON message protocol: a root ``timestamp`` (the
estimate's sensor time in s; tick "use field as timestamp" and name ``timestamp``) and nested objects of
numbers, which PlotJuggler flattens to series such as ``/state/px``. Only numbers (booleans as 0/1, no
arrays) so every leaf becomes a series::

    {"timestamp": 12.345,
     "state": {"px": 1.23, "py": ...},            # every state element by name (SI, radians)
     "sd": {"px": 0.05, ...},                      # its 1-sigma
     "innovation": {"uwb": {"nis": 0.8, "ratio": 0.06, "accepted": 1, "dim": 1,
                            "y0": 0.012, "sqrt_S0": 0.11}}}   # only on an update, for its sensor

``ratio`` is NIS / gate threshold (nan-free: omitted when the sensor has no gate); ``yK``/``sqrt_SK`` are
the innovation element K (measurement units) and the square root of S's diagonal. Non-finite numbers
are sent as ``null`` (strict JSON). A datagram that cannot be sent (nobody listening: ICMP refused) is
counted in ``errors`` and dropped; the run never waits for the network.
"""
from __future__ import annotations

import json
import math
import socket
from typing import Any, Mapping

import numpy as np

from fusion.api import ConfigError, Estimate, HasThreshold, StateLayout, has

DEFAULT_PORT = 9870  # PlotJuggler's UDP server default


def parse_address(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[::1]:9870`` for IPv6, ``:9870`` for localhost) -> (host, port); ConfigError else."""
    host, sep, port = text.rpartition(":")
    if not sep:
        raise ConfigError(f"--udp {text}: expected HOST:PORT, e.g. 127.0.0.1:{DEFAULT_PORT}")
    host = host.strip("[]") or "127.0.0.1"
    try:
        number = int(port)
    except ValueError:
        number = -1
    if not 0 < number < 65536:
        raise ConfigError(f"--udp {text}: the port must be a number from 1 to 65535, e.g. {host}:{DEFAULT_PORT}")
    return host, number


def _num(v: float) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


class UdpStream:
    """A pipeline sink that sends each estimate to ``(host, port)`` as one JSON datagram."""

    def __init__(self, host: str, port: int, layout: StateLayout, gates: Mapping[str, Any] | None = None):
        try:
            infos = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
        except socket.gaierror as exc:
            raise ConfigError(f"--udp {host}:{port}: cannot resolve {host}: {exc.strerror}") from None
        family, _, _, _, self.address = infos[0]
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        self.names = [n for b in layout.blocks for n in b.element_names()]
        self.gates = dict(gates or {})
        self.thresholds = {n: g.threshold for n, g in self.gates.items() if has(g, HasThreshold)}
        self.sent = 0
        self.errors = 0

    def message(self, est: Estimate) -> dict[str, Any]:
        """The JSON object for one estimate (see the module)."""
        x, sd = est.belief.x, est.belief.sd
        out: dict[str, Any] = {"timestamp": _num(est.t),
                               "state": {n: _num(v) for n, v in zip(self.names, x)},
                               "sd": {n: _num(v) for n, v in zip(self.names, sd)}}
        up = est.update
        if up is not None and est.sensor is not None:
            y = np.asarray(up.innovation, dtype=float).reshape(-1)
            S = np.asarray(up.S, dtype=float).reshape(y.size, y.size)
            inn: dict[str, Any] = {"nis": _num(up.nis), "accepted": int(bool(up.accepted)), "dim": int(y.size)}
            threshold = self.thresholds.get(est.sensor)
            if threshold is not None and y.size:
                inn["ratio"] = _num(up.nis / threshold(y.size))
            for k in range(y.size):
                inn[f"y{k}"] = _num(y[k])
                inn[f"sqrt_S{k}"] = _num(math.sqrt(max(S[k, k], 0.0)))
            out["innovation"] = {est.sensor: inn}
        return out

    def on_estimate(self, est: Estimate) -> None:
        data = json.dumps(self.message(est), separators=(",", ":"), allow_nan=False).encode()
        try:
            self.sock.sendto(data, self.address)
            self.sent += 1
        except OSError:  # refused, buffer full, network down: the view never waits for a listener
            self.errors += 1

    def close(self) -> None:
        self.sock.close()
