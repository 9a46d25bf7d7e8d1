"""Built-in process: each module holds one component; this module registers them."""
from fusion import hookimpl

# name -> module:class, registered lazily: a module is imported when a config asks for its component
# (start-up: a run imports the few plugins it uses, not all of them).
PROCESSES = {
    "pv": "fusion_plugins.process.pv:ConstantVelocity",
    "ins": "fusion_plugins.process.ins:Ins",
    "firing_clock": "fusion_plugins.process.firing_clock:FiringClock",
    "static_orientation": "fusion_plugins.process.static_orientation:StaticOrientation",
    "omni": "fusion_plugins.process.omni:Omni",
    "gyro_attitude": "fusion_plugins.process.gyro_attitude:GyroAttitude",
}


@hookimpl
def fusion_register_components(registry):
    for name, target in PROCESSES.items():
        registry.add_lazy("process", name, target)
