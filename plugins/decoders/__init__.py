"""Built-in decoders: each module holds one component; this module registers them."""
from fusion import hookimpl


@hookimpl
def fusion_register_components(registry):
    from fusion_plugins.decoders.line import LineDecoder
    from fusion_plugins.decoders.nmea import NmeaDecoder

    registry.add(LineDecoder)
    registry.add(NmeaDecoder)
