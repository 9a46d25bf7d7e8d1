"""Built-in simulators: each module holds one component; this module registers them.

Registered lazily (by module path, imported when a scenario asks for one): they pull in scipy.spatial
and pymap3d, which ``fusion run`` and ``fusion tui`` never need.
"""
from fusion import hookimpl

SIMULATORS = {
    "imu": "fusion_plugins.simulators.imu:ImuSimulator",
    "range": "fusion_plugins.simulators.range:RangeSimulator",
    "arrival_time": "fusion_plugins.simulators.arrival:ArrivalTimeSimulator",
    "gps": "fusion_plugins.simulators.gps:GpsSimulator",
    "magnetometer": "fusion_plugins.simulators.magnetometer:MagnetometerSimulator",
    "position": "fusion_plugins.simulators.position:PositionSimulator",
}


@hookimpl
def fusion_register_components(registry):
    for name, target in SIMULATORS.items():
        registry.add_lazy("simulator", name, target)
