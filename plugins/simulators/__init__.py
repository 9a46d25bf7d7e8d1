"""Built-in simulators: each module holds one component; this module registers them."""
from fusion import hookimpl


@hookimpl
def fusion_register_components(registry):
    from fusion_plugins.simulators.arrival import ArrivalTimeSimulator
    from fusion_plugins.simulators.gps import GpsSimulator
    from fusion_plugins.simulators.imu import ImuSimulator
    from fusion_plugins.simulators.magnetometer import MagnetometerSimulator
    from fusion_plugins.simulators.position import PositionSimulator
    from fusion_plugins.simulators.range import RangeSimulator

    for cls in (ImuSimulator, RangeSimulator, ArrivalTimeSimulator, GpsSimulator, MagnetometerSimulator,
                PositionSimulator):
        registry.add(cls)
