"""Core sinks, registered as plugins like any other."""
from fusion import hookimpl


@hookimpl
def fusion_register_components(registry):
    from fusion.sinks.estimates import EstimateWriter

    registry.add(EstimateWriter)
    registry.add_lazy("sink", "mcap", "fusion.sinks.mcap_out:McapSink")   # imports mcap and rosbags when used
