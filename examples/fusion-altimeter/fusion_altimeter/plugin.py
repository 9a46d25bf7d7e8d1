"""The example third-party package's plugin module: a barometric altimeter measurement (z = offset - p_z,
height up, NED state) and its simulator, a process model (``hover``), a UDP source (udp://HOST:PORT) and a
TSV sink (.tsv): one of each kind an author is likely to add."""
from __future__ import annotations

import numpy as np

from fusion import hookimpl
from fusion.api import ConfigError, MalformedMessage, MeasurementModel, Observation, Params


class AltimeterParams(Params):
    offset: float = 0.0


class Altimeter(MeasurementModel[AltimeterParams]):
    """Height above the reference (m, up) from the NED position block ``p`` (needs 3 axes).

    Params: ``offset``: height of the reference above the navigation origin (m)."""

    name = "altimeter"
    dim = 1
    linear = True   # h is affine in x: the kf accepts it

    Params = AltimeterParams

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        lay = self.context.layout
        if lay is None or "p" not in lay or lay.block("p").size != 3:
            raise ConfigError("altimeter needs a 3-D position block 'p'")
        self._iz = lay["p"].start + 2

    def h(self, x: np.ndarray) -> np.ndarray:
        return self.params.offset - x[..., self._iz : self._iz + 1]

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        H = np.zeros((1, x.shape[-1]))
        H[0, self._iz] = -1.0
        return H

    def observe(self, message):
        z = message.floats()
        if z.shape != (1,) or not np.isfinite(z[0]):
            raise MalformedMessage(f"altimeter expects one finite height (m), got {message.values!r}")
        return Observation(message.t, z, self)


@hookimpl
def fusion_register_components(registry):
    from fusion_altimeter.hover import Hover
    from fusion_altimeter.tsv_sink import TsvTrack
    from fusion_altimeter.udp_source import UdpSource

    registry.add(Altimeter)
    registry.add(Hover)
    registry.add_lazy("simulator", "altimeter", "fusion_altimeter.altimeter_sim:AltimeterSimulator")
    registry.add(UdpSource)   # fusion run CONFIG --input udp://127.0.0.1:5005
    registry.add(TsvTrack)    # fusion run CONFIG --output track.tsv
