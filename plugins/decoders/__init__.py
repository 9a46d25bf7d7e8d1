"""Built-in decoders: each module holds one component; this module registers them."""
from fusion import hookimpl


@hookimpl
def fusion_register_components(registry):
    pass
