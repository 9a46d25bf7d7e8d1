"""Built-in importers of ``fusion import`` (PX4 ULog, ArduPilot DataFlash, CSV by a mapping file,
ROS 1 / ROS 2 bags),
registered as plugins of kind ``importer`` like any other: a third party adds a format the same way.
Each importer imports its reader library (pyulog, pymavlink) at first use, and the importers are
registered lazily (imported when ``fusion import`` lists or uses them), so start-up stays fast.
The decoder ``gps_fields`` reads the geodetic ``gps`` lines the importers write (fusion.importers.gps_decoder)."""
from fusion import hookimpl

IMPORTERS = {
    "ulog": "fusion.importers.ulog:UlogImporter",
    "dataflash": "fusion.importers.dataflash:DataflashImporter",
    "csv": "fusion.importers.csvmap:CsvImporter",
    "rosbag": "fusion.importers.rosbag:RosbagImporter",
}
DECODERS = {
    "gps_fields": "fusion.importers.gps_decoder:GpsFieldsDecoder",
}


@hookimpl
def fusion_register_components(registry):
    for name, target in IMPORTERS.items():
        registry.add_lazy("importer", name, target)
    for name, target in DECODERS.items():
        registry.add_lazy("decoder", name, target)
