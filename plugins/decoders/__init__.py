"""Built-in decoders: each module holds one component; this module registers them."""
from fusion import hookimpl

# name -> module:class, registered lazily: a module is imported when a config asks for its component
# (start-up: a run imports the few plugins it uses, not all of them).
DECODERS = {
    "line": "fusion_plugins.decoders.line:LineDecoder",
    "nmea": "fusion_plugins.decoders.nmea:NmeaDecoder",
}


@hookimpl
def fusion_register_components(registry):
    for name, target in DECODERS.items():
        registry.add_lazy("decoder", name, target)
