"""Core sources, registered as plugins like any other."""
from fusion import hookimpl


@hookimpl
def fusion_register_components(registry):
    pass
