"""Built-in measurement: each module holds one component; this module registers them."""
from fusion import hookimpl


@hookimpl
def fusion_register_components(registry):
    from fusion_plugins.measurement.range import RangeModel
    from fusion_plugins.measurement.position import Position
    from fusion_plugins.measurement.arrival_time import ArrivalTime
    from fusion_plugins.measurement.direction import Direction

    from fusion_plugins.measurement.gps import Gps
    from fusion_plugins.measurement.magnetometer import Magnetometer
    from fusion_plugins.measurement.attitude import Attitude
    from fusion_plugins.measurement.quat_norm import QuatNorm

    registry.add(RangeModel)
    registry.add(Position)
    registry.add(ArrivalTime)
    registry.add(Direction)
    registry.add(Gps)
    registry.add(Magnetometer)
    registry.add(Attitude)
    registry.add(QuatNorm)
