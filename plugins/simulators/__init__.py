"""Built-in simulators: each module holds one component; this module registers them."""
from fusion import hookimpl


@hookimpl
def fusion_register_components(registry):
    from fusion_plugins.simulators.imu import ImuSimulator
    from fusion_plugins.simulators.range import RangeSimulator

    registry.add(ImuSimulator)
    registry.add(RangeSimulator)
