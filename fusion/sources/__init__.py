"""Core sources (recording replay, serial port), registered as plugins like any other."""
from fusion import hookimpl


@hookimpl
def fusion_register_components(registry):
    from fusion.sources.recording import RecordingSource
    from fusion.sources.serial import SerialSource

    registry.add(RecordingSource)
    registry.add(SerialSource)
    registry.add_lazy("source", "rosbag", "fusion.sources.bag:BagSource")   # imports rosbags when used
