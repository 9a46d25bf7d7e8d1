"""Built-in measurement: each module holds one component; this module registers them."""
from fusion import hookimpl

# name -> module:class, registered lazily: a module is imported when a config asks for its component
# (start-up: a run imports the few plugins it uses, not all of them).
MEASUREMENTS = {
    "range": "fusion_plugins.measurement.range:RangeModel",
    "position": "fusion_plugins.measurement.position:Position",
    "arrival_time": "fusion_plugins.measurement.arrival_time:ArrivalTime",
    "direction": "fusion_plugins.measurement.direction:Direction",
    "gps": "fusion_plugins.measurement.gps:Gps",
    "magnetometer": "fusion_plugins.measurement.magnetometer:Magnetometer",
    "attitude": "fusion_plugins.measurement.attitude:Attitude",
    "quat_norm": "fusion_plugins.measurement.quat_norm:QuatNorm",
    "pose": "fusion_plugins.measurement.pose:Pose",
    "twist": "fusion_plugins.measurement.twist:Twist",
    "imu": "fusion_plugins.measurement.imu:Imu",
    "gravity": "fusion_plugins.measurement.gravity:Gravity",
    "magnetometer_checked": "fusion_plugins.measurement.magnetometer_checked:MagnetometerChecked",
}


@hookimpl
def fusion_register_components(registry):
    for name, target in MEASUREMENTS.items():
        registry.add_lazy("measurement", name, target)
