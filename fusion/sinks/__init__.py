"""Core sinks, registered as plugins like any other."""
from fusion import hookimpl


@hookimpl
def fusion_register_components(registry):
    from fusion.sinks.estimates import EstimateWriter

    registry.add(EstimateWriter)
